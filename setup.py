"""The compiled part of pcdet, beside pyproject.toml (which holds everything else): small C kernels for
``pcdet.graph`` (common neighbours of each edge, and the length and angle tests of candidate pairs),
``pcdet.residuals`` (correspondences within a radius of many poses, and Tukey-weighted Kabsch sums), ``pcdet.align``
(the rotations of many Kabsch problems, and the greedy choice of distinct poses), ``pcdet.grid`` (the nearest point
within a short radius, on a hashed voxel grid), ``pcdet.features`` (FPFH descriptors, their neighbours found on that
grid), ``pcdet.cloud`` (normals, their neighbours found alike), ``pcdet.lrf`` (SHOT frames, alike) and
``pcdet.grouping.hough`` (the votes' trilinear sums, and each peak's voters). ``optional``: where no C compiler is at
hand the install goes on without them, and pcdet computes the same results with numpy and scipy, or with open3d: FPFH
(which orders neighbours at the same distance by its own rule) and normals (the same axes, rounded otherwise)."""
from setuptools import Extension, setup

# no fused multiply-adds: the length test must round as numpy's float32 arithmetic does (pcdet/_graph.c), the
# residuals are summed in one stated order (pcdet/_residuals.c), the grid's distances as the KD-tree's
# (pcdet/_grid.c), the FPFH pair features as open3d's (pcdet/_fpfh.c) and the Hough votes as numpy's (pcdet/_votes.c)
KERNELS = ("_graph", "_residuals", "_grid", "_fpfh", "_align", "_normals", "_lrf", "_votes")
HEADERS = ["pcdet/_cells.h", "pcdet/_near.h", "pcdet/_eigen.h"]
setup(ext_modules=[Extension(f"pcdet.{name}", [f"pcdet/{name}.c"], depends=HEADERS,
                             extra_compile_args=["-ffp-contract=off"], optional=True)
                   for name in KERNELS])
