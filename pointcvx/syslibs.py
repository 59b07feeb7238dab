"""System shared libraries that the binary wheels pointcvx uses link against.

open3d's Linux wheel links ``libusb-1.0.so.0``, which minimal machines (containers, CI images,
cloud VMs) often lack. The pip package ``libusb-package`` (a dependency) ships a copy;
:func:`preload_libusb` loads the system's library if there is one, else that copy, with
``RTLD_GLOBAL`` before anything imports open3d, so the dynamic loader finds the soname already
loaded. ``import pointcvx`` does it once, so a user's own ``import open3d`` afterwards works too.

Any other library a wheel needs and the machine lacks (open3d: GL, EGL, X11; gmsh: GLU and
the X client libraries) cannot come from pip: :func:`missing_library` reads the loader's message
and :class:`~pointcvx.errors.MissingLibraryError` names the package that provides it.
"""

from __future__ import annotations

import ctypes
import importlib.util
import re
import sys
from pathlib import Path

from .errors import MissingLibraryError

LIBUSB = "libusb-1.0.so.0"

#: Debian/Ubuntu packages of the libraries open3d and gmsh link (soname stem -> package).
APT_PACKAGES = {
    "libGL": "libgl1", "libEGL": "libegl1", "libOpenGL": "libopengl0", "libGLX": "libglx0",
    "libGLdispatch": "libglvnd0", "libGLU": "libglu1-mesa", "libX11": "libx11-6",
    "libXext": "libxext6", "libXrender": "libxrender1", "libXcursor": "libxcursor1",
    "libXfixes": "libxfixes3", "libXft": "libxft2", "libXinerama": "libxinerama1",
    "libxcb": "libxcb1", "libXau": "libxau6", "libXdmcp": "libxdmcp6",
    "libfontconfig": "libfontconfig1", "libfreetype": "libfreetype6", "libudev": "libudev1",
    "libidn2": "libidn2-0", "libgomp": "libgomp1", "libexpat": "libexpat1", "libpng16": "libpng16-16",
    "libbsd": "libbsd0", "libbrotlidec": "libbrotli1", "libbrotlicommon": "libbrotli1",
    "libz": "zlib1g",
}

_MISSING = re.compile(r"([\w.+-]+\.so(?:\.[\w.]+)?): cannot open shared object file")
_state: dict[str, str | None] = {}


def bundled_libusb() -> Path | None:
    """The ``libusb-1.0.so`` inside the ``libusb-package`` wheel, if it is installed."""
    try:
        spec = importlib.util.find_spec("libusb_package")
    except (ImportError, ValueError):  # blocked (sys.modules entry None) or a broken install
        return None
    if spec is None or not spec.origin:
        return None
    path = Path(spec.origin).parent / "libusb-1.0.so"
    return path if path.is_file() else None


def preload_libusb() -> str | None:
    """Load libusb-1.0 process-wide so that open3d's native module links (Linux only).

    Returns where it came from: ``"system"``, the path of the bundled copy, or None (not Linux,
    or neither is loadable; importing open3d then fails with :class:`MissingLibraryError`).
    Runs once per process; later calls return the first answer.
    """
    if "libusb" in _state:
        return _state["libusb"]
    found = None
    if sys.platform.startswith("linux"):
        try:
            ctypes.CDLL(LIBUSB, mode=ctypes.RTLD_GLOBAL)
            found = "system"
        except OSError:
            path = bundled_libusb()
            if path is not None:
                try:
                    ctypes.CDLL(str(path), mode=ctypes.RTLD_GLOBAL)
                    found = str(path)
                except OSError:
                    found = None
    _state["libusb"] = found
    return found


def missing_library(exc: BaseException) -> str | None:
    """The shared library (soname) whose absence the loader reported in ``exc``, or None."""
    match = _MISSING.search(str(exc))
    return match.group(1) if match else None


def install_hint(library: str) -> str:
    """What to install for ``library`` (a soname such as ``libGLU.so.1``)."""
    if library.startswith("libusb-1.0"):
        return "pip install libusb-package (or apt-get install libusb-1.0-0)"
    package = APT_PACKAGES.get(library.split(".so")[0])
    if package is not None:
        return f"apt-get install {package} (Debian/Ubuntu)"
    return "install it with the system's package manager"


#: open3d's plotly drawing, which ``import open3d`` runs eagerly (it imports dash and plotly:
#: 0.3-0.5 s of CPU in every process that touches open3d, about half of open3d's import).
PLOTLY_MODULE = "open3d.visualization.draw_plotly"
PLOTLY_FUNCTIONS = ("get_plotly_fig", "draw_plotly", "draw_plotly_server")


def defer_open3d_plotly() -> bool:
    """Put a stand-in for :data:`PLOTLY_MODULE` in ``sys.modules`` before open3d is imported:
    its functions load the real module on first call and forward to it, so open3d's plotly
    drawing still works for a user who calls it. False (nothing done) when open3d is already
    imported or its file is not where expected."""
    import importlib.util
    import os
    import types

    if "open3d" in sys.modules or PLOTLY_MODULE in sys.modules:
        return False
    spec = importlib.util.find_spec("open3d")
    if spec is None or not spec.submodule_search_locations:
        return False
    path = os.path.join(spec.submodule_search_locations[0], "visualization", "draw_plotly.py")
    if not os.path.isfile(path):
        return False

    def real():
        module = sys.modules.get(PLOTLY_MODULE)
        if module is not None and module is not stub:
            return module
        loaded = importlib.util.spec_from_file_location(PLOTLY_MODULE, path)
        module = importlib.util.module_from_spec(loaded)
        sys.modules[PLOTLY_MODULE] = module
        loaded.loader.exec_module(module)
        return module

    stub = types.ModuleType(PLOTLY_MODULE, "pointcvx.syslibs's stand-in: loads the real module on first use.")
    for name in PLOTLY_FUNCTIONS:
        def forward(*args, _name=name, **kwargs):
            return getattr(real(), _name)(*args, **kwargs)

        forward.__name__ = name
        setattr(stub, name, forward)
    sys.modules[PLOTLY_MODULE] = stub
    return True


def import_open3d():
    """The ``open3d`` module; :class:`MissingLibraryError` if a system library it links is missing.
    Its plotly drawing is loaded on first use (:func:`defer_open3d_plotly`)."""
    preload_libusb()
    defer_open3d_plotly()
    try:
        import open3d
    except (ImportError, OSError) as exc:
        library = missing_library(exc)
        if library is None:
            raise
        raise MissingLibraryError("open3d", library, install_hint(library)) from None
    return open3d
