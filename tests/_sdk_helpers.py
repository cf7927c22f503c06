"""Helpers for the hardware-SDK tests (not a test module).

An SDK that is not installed, or installed but unable to load (a missing system library, say),
skips the tests that need it with the reason; with CALIBGRAPH_HW_SDK_REQUIRED=1 (CI, which
installs every extra) it fails them instead. ``pytest.importorskip`` is not enough: since pytest 9
it lets an ImportError that is not a ModuleNotFoundError (``libusb-1.0.so.0: cannot open shared
object file``) through, which stops the whole run at collection."""

import importlib
import os

import pytest


def sdk_unavailable(msg: str):
    """Skip with ``msg`` (the whole module when called at import), or fail in CI."""
    if os.environ.get("CALIBGRAPH_HW_SDK_REQUIRED") == "1":
        pytest.fail(msg + " (and CALIBGRAPH_HW_SDK_REQUIRED=1)", pytrace=False)
    pytest.skip(msg, allow_module_level=True)


def import_sdk(name: str, install_hint: str):
    """The module ``name``, or a skip saying why it is unavailable and how to install it."""
    try:
        return importlib.import_module(name)
    except ModuleNotFoundError as e:
        sdk_unavailable(f"{name} is not installed ({install_hint}) [{e}]")
    except Exception as e:  # installed, but it (or a library it needs) fails to load
        sdk_unavailable(f"{name} is installed but cannot be imported: {type(e).__name__}: {e} ({install_hint})")


def require_realsense():
    """pyrealsense2 as drivers.realsense loaded it: rclpy's libraries first, then libusb from the
    libusb-package wheel (see the notes there), then the SDK."""
    import drivers.realsense as drv

    if drv._rs is None:
        sdk_unavailable(f"pyrealsense2 is unavailable (pip install 'calibgraph[realsense]') [{drv._IMPORT_ERROR}]")
    return drv._rs
