"""Routes and logs named by URL (``https://…``, ``s3://…``, any scheme fsspec knows).

A fleet's logs live on shared storage more often than on the machine that scores them: ``excite
batch``, ``excite mine`` and their Dask workers accept a URL wherever they accept a route file,
and the process that reads a route (a worker, on a cluster) copies it to a temporary folder
first, through `fsspec <https://filesystem-spec.readthedocs.io>`_ (HTTP(S) comes with excite;
other schemes need fsspec's package for them, e.g. ``s3fs``: the error says which). The copy
keeps the file's name (its format is told from it) and is deleted once the route has been
read. A URL that names a folder (a ROS 2 bag) is copied whole. The copy is bounded by
:data:`MAX_FETCH_BYTES`, checked while it streams.
"""

from __future__ import annotations

import posixpath
import re
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

from ..errors import RouteError

MAX_FETCH_BYTES = 8 * 2**30
"""Most bytes copied for one route (a 4-hour bag is ~2 GB)."""

_URL = re.compile(r"^[A-Za-z][A-Za-z0-9+.-]*://")


def is_url(text: object) -> bool:
    """Whether ``text`` is a URL (``scheme://…``) rather than a local path."""
    return isinstance(text, str) and bool(_URL.match(text))


def name_of(url: str) -> str:
    """The file name a URL ends with (a route's name in tables), without query or fragment."""
    path = re.split(r"[?#]", url, maxsplit=1)[0]
    return posixpath.basename(path.rstrip("/")) or url


@contextmanager
def local(path: str | None, max_bytes: int = MAX_FETCH_BYTES) -> Iterator[str | None]:
    """``path`` itself when it is local (or None); for a URL, a local copy for the duration of
    the ``with`` block. Errors raised inside the block name the URL, not the copy."""
    if not is_url(path):
        yield path
        return
    assert path is not None
    if any(c in name_of(path) for c in "*[]"):
        raise RouteError(f"{path}: globs are not expanded in URLs: name each file")
    with tempfile.TemporaryDirectory(prefix="excite-fetch-") as d:
        dst = Path(d) / name_of(path)
        _fetch(path, dst, max_bytes)
        try:
            yield str(dst)
        except Exception as exc:
            _rename(exc, str(dst), path)
            raise


def _rename(exc: BaseException, copy: str, url: str) -> None:
    """Put the URL where an error names the local copy (its message, an OSError's file name)."""
    exc.args = tuple(a.replace(copy, url) if isinstance(a, str) else a for a in exc.args)
    if isinstance(getattr(exc, "filename", None), str):
        exc.filename = exc.filename.replace(copy, url)  # type: ignore[attr-defined]
    if isinstance(getattr(exc, "source", None), str):
        exc.source = exc.source.replace(copy, url)  # type: ignore[attr-defined]


def _fetch(url: str, dst: Path, max_bytes: int) -> None:
    import fsspec  # a dependency of Dask's; imported only when a URL is read

    try:
        fs, rpath = fsspec.core.url_to_fs(url)
    except ImportError as exc:  # the scheme's implementation is not installed
        raise RouteError(f"cannot read {url}: {exc}") from None
    except ValueError as exc:  # an unknown scheme
        raise RouteError(f"cannot read {url}: {exc}") from None
    budget = [max_bytes]  # bytes still allowed, shared by every file of a folder
    try:
        # a folder only when it is a ROS 2 bag (its metadata.yaml): an HTTP page with links
        # (a listing, a login page) looks like a folder to fsspec
        if fs.isdir(rpath) and fs.exists(posixpath.join(rpath.rstrip("/"), "metadata.yaml")):
            base = rpath.rstrip("/")
            for f in fs.find(base):
                rel = posixpath.relpath(f, base)
                target = (dst / rel).resolve()
                if rel.startswith("..") or not target.is_relative_to(dst.resolve()):
                    raise RouteError(f"{url}: {f} lies outside the folder")
                _copy(fs, f, target, url, budget, max_bytes)
        else:
            _copy(fs, rpath, dst, url, budget, max_bytes)
    except RouteError:
        raise
    except FileNotFoundError:
        raise RouteError(f"{url}: not found") from None
    except Exception as exc:  # what the storage said (HTTP status, connection refused, access denied)
        raise RouteError(f"cannot read {url}: {type(exc).__name__}: {exc}".splitlines()[0][:300]) from None


def _copy(fs, rpath: str, dst: Path, url: str, budget: list[int], max_bytes: int) -> None:
    dst.parent.mkdir(parents=True, exist_ok=True)
    # block_size=0: one streaming read (HTTP servers need not support range requests)
    with fs.open(rpath, "rb", block_size=0) as src, open(dst, "wb") as out:
        while chunk := src.read(1 << 20):
            budget[0] -= len(chunk)
            if budget[0] < 0:
                raise RouteError(f"{url}: over the limit of {max_bytes} bytes for one route")
            out.write(chunk)
