"""Import Open3D on machines without the system libusb: preload the copy shipped by `libusb-package`."""
from __future__ import annotations

import ctypes
import functools


@functools.lru_cache(maxsize=None)
def import_open3d():
    """Return the `open3d` module, loading libusb-1.0.so.0 from `libusb-package` first if the system lacks it."""
    try:
        import open3d
        return open3d
    except ImportError as error:
        if "libusb" not in str(error):
            raise
    import libusb_package

    library = libusb_package.get_library_path()
    if library is None:
        raise ImportError("open3d needs libusb-1.0.so.0: `apt-get install libusb-1.0-0` or "
                          "`pip install libusb-package`")
    ctypes.CDLL(str(library), mode=ctypes.RTLD_GLOBAL)
    import open3d
    return open3d
