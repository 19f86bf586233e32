"""The one compiled part of pcdet, beside pyproject.toml (which holds everything else): a small C kernel for
``pcdet.graph.common_neighbours``. ``optional``: where no C compiler is at hand the install goes on without it, and
pcdet computes the same counts with scipy."""
from setuptools import Extension, setup

setup(ext_modules=[Extension("pcdet._graph", ["pcdet/_graph.c"], optional=True)])
