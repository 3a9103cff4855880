"""The installed package version, written into every checkpoint, model and report."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("vprsnn-export")
except PackageNotFoundError:  # running from a source tree that was never installed
    __version__ = "0.0.0+unknown"
