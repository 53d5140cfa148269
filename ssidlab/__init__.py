"""ssidlab: the application layer (command line, bundled examples) over ssid, daq, drivers, tui."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("ssidlab")
except PackageNotFoundError:  # running from a source tree that was never installed
    __version__ = "0.0.0+source"
