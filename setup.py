"""The one compiled part of pcdet, beside pyproject.toml (which holds everything else): small C kernels for
``pcdet.graph`` (common neighbours of each edge, and the length test of candidate pairs). ``optional``: where no C
compiler is at hand the install goes on without them, and pcdet computes the same results with numpy and scipy."""
from setuptools import Extension, setup

# no fused multiply-adds: the length test must round as numpy's float32 arithmetic does (pcdet/_graph.c)
setup(ext_modules=[Extension("pcdet._graph", ["pcdet/_graph.c"], extra_compile_args=["-ffp-contract=off"],
                             optional=True)])
