"""The native module of excite (``excite._native``: every C file under ``excite/``, among them the
factor kernels generated from the kinds' statements), compiled with the system C compiler when
the package is built or installed. Everything else is in pyproject.toml."""

import importlib.util
from pathlib import Path

from setuptools import Extension, setup

ROOT = Path(__file__).resolve().parent
# excite/core/native.py lists the sources and their hash (standard library only: nothing of
# excite's dependencies is installed yet)
_spec = importlib.util.spec_from_file_location("excite_native_build", ROOT / "excite" / "core" / "native.py")
native = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(native)

setup(ext_modules=[Extension(
    "excite._native",
    sources=[str(p.relative_to(ROOT)) for p in native.sources(ROOT / "excite")],
    depends=[str(p.relative_to(ROOT)) for p in sorted((ROOT / "excite").rglob("*.h"))],
    define_macros=[native.define(ROOT / "excite")],
    extra_compile_args=[f for f in native.FLAGS if f != "-fPIC"],
)])
