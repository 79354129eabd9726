"""Backend selection: find libLLVM, pick the Mitsuba variant, describe the device.

Every entry point calls :func:`init_backend` before touching ``mitsuba``:
it validates libLLVM *before* Dr.Jit can load a bad one (LLVM 15 aborts the
process), chooses ``cuda_ad_rgb`` when a GPU is usable and ``llvm_ad_rgb``
otherwise (``NIRC_BENCH_VARIANT`` or the ``variant`` argument override), and
returns the ``mitsuba`` module with the variant set.
"""

from __future__ import annotations

import os
import platform
from functools import cache
from typing import Any

from renderers.llvm import LLVMNotFoundError, find_libllvm

SUPPORTED_VARIANTS = ("llvm_ad_rgb", "cuda_ad_rgb")


class BackendError(RuntimeError):
    """The requested rendering backend cannot be used here (message says why)."""


def _cuda_usable() -> bool:
    """True when Dr.Jit's CUDA backend can start (a driver and a GPU are present)."""
    import drjit as dr

    try:
        return bool(dr.has_backend(dr.JitBackend.CUDA))
    except Exception:  # noqa: BLE001 - any failure to probe means "no GPU"
        return False


def default_variant() -> str:
    requested = os.environ.get("NIRC_BENCH_VARIANT")
    if requested:
        return requested
    return "cuda_ad_rgb" if _cuda_usable() else "llvm_ad_rgb"


@cache
def _configure_llvm() -> str:
    """Point Dr.Jit at a libLLVM >= 16; returns its path. Cached per process."""
    try:
        lib = find_libllvm()
    except LLVMNotFoundError as err:
        raise BackendError(str(err)) from None
    os.environ["DRJIT_LIBLLVM_PATH"] = lib.path
    return lib.path


def init_backend(variant: str | None = None) -> Any:
    """Select the Mitsuba variant (validating libLLVM first) and return ``mitsuba``."""
    variant = variant or default_variant()
    if variant not in SUPPORTED_VARIANTS:
        raise BackendError(
            f"unsupported variant '{variant}'; choose one of {', '.join(SUPPORTED_VARIANTS)}"
        )
    if variant.startswith("llvm"):
        _configure_llvm()
    import mitsuba as mi

    if mi.variant() != variant:
        try:
            mi.set_variant(variant)
        except Exception as err:  # noqa: BLE001 - surface as a clear backend error
            raise BackendError(f"cannot use Mitsuba variant '{variant}': {err}") from None
    return mi


def _cpu_model() -> str:
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as cpuinfo:
            for line in cpuinfo:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def cpu_device_key() -> str:
    """The ``device_key`` of renders on this machine's CPU (``llvm`` backend), known
    without starting Dr.Jit (the service estimates job times with it)."""
    return f"llvm:{_cpu_model()}:{os.cpu_count()}"


def device_info() -> dict[str, Any]:
    """Provenance of the device a render ran on: stored with every result.

    Timing comparisons are only valid between results with equal ``device_key``.
    """
    import drjit as dr
    import mitsuba as mi

    variant = mi.variant()
    info: dict[str, Any] = {
        "variant": variant,
        "backend": "cuda" if variant.startswith("cuda") else "llvm",
        "cpu": _cpu_model(),
        "cores": os.cpu_count(),
        "platform": platform.platform(),
        "mitsuba": mi.__version__,
        "drjit": dr.__version__,
    }
    if info["backend"] == "llvm":
        info["libllvm"] = os.environ.get("DRJIT_LIBLLVM_PATH", "")
        info["device"] = info["cpu"]
    else:
        info["device"] = _gpu_name()
    info["device_key"] = (cpu_device_key() if info["backend"] == "llvm"
                          else f"{info['backend']}:{info['device']}:{info['cores']}")
    return info


def _gpu_name() -> str:
    """GPU name from nvidia-smi, else the CUDA compute capability Dr.Jit reports."""
    import subprocess

    try:
        out = subprocess.run(
            ["nvidia-smi", "--query-gpu=name,driver_version", "--format=csv,noheader"],
            capture_output=True, text=True, timeout=10, check=True,
        ).stdout.strip().splitlines()
        if out:
            return out[0].strip()
    except (OSError, subprocess.SubprocessError):
        pass
    import drjit as dr

    return f"CUDA GPU (compute capability {dr.detail.cuda_compute_capability()})"


def host_runs_kernels() -> bool:
    """Whether the selected variant runs its kernels on this host's cores (LLVM), so
    that the process's CPU time says how much of the cores it got (renderers.load)."""
    import mitsuba as mi

    return not (mi.variant() or "").startswith("cuda")
