"""The compiled part of pcdet, beside pyproject.toml (which holds everything else): small C kernels for
``pcdet.graph`` (common neighbours of each edge, and the length and angle tests of candidate pairs),
``pcdet.residuals`` (correspondences within a radius of many poses, and Tukey-weighted Kabsch sums) and
``pcdet.grid`` (the nearest point within a short radius, on a hashed voxel grid). ``optional``: where no C compiler
is at hand the install goes on without them, and pcdet computes the same results with numpy and scipy."""
from setuptools import Extension, setup

# no fused multiply-adds: the length test must round as numpy's float32 arithmetic does (pcdet/_graph.c), the
# residuals are summed in one stated order (pcdet/_residuals.c), and the grid's distances as the KD-tree's
# (pcdet/_grid.c)
setup(ext_modules=[Extension(f"pcdet.{name}", [f"pcdet/{name}.c"], extra_compile_args=["-ffp-contract=off"],
                             optional=True) for name in ("_graph", "_residuals", "_grid")])
