"""Import open3d on machines without the system libusb.

open3d's shared library links against ``libusb-1.0.so.0``, which minimal machines lack. The pip
package ``libusb-package`` ships that library; loading it globally first lets ``import open3d``
resolve the symbol without a system install (docs/DECISIONS.md, "open3d without libusb").
"""

from __future__ import annotations

import ctypes
import functools


@functools.cache
def open3d():
    """Return the open3d module, loading the bundled libusb first when needed."""
    try:
        import libusb_package

        ctypes.CDLL(str(libusb_package.get_library_path()), mode=ctypes.RTLD_GLOBAL)
    except (ImportError, OSError):
        pass
    import open3d as o3d

    return o3d
