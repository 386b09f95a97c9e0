"""xvmatch: find the same people in an egocentric/horizontal camera and a top/overview camera.

The top-level folders of the repository are the subpackages of this one import package
(``xvmatch.geometry``, ``xvmatch.datasets``, ...), mapped in ``pyproject.toml``.
"""

__version__ = "0.1.0"
