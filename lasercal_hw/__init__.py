"""lasercal: find the pose of a 2D laser scanner in a robot's base frame with a thin rod."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("lasercal")
except PackageNotFoundError:  # running from a source tree that was not installed
    __version__ = "0+unknown"
