"""Shrink a site-packages tree in place (the image's venv, after pip is done with it):

- test suites (every directory named ``tests``: numpy, scipy, pandas-free matplotlib,
  llvmlite, dask, distributed, ... ship theirs; nothing imports them at run time) and casadi's C
  headers (``casadi/include``: only casadi's code generation / JIT compiles against them, excite
  calls ipopt through ``nlpsol``) are removed;
- identical files become hard links of one file: wheels cannot hold symlinks, so casadi ships
  each shared library two or three times (``libfoo.so``, ``libfoo.so.3``, ``libfoo.so.3.7``), and
  scipy and casadi each carry the same libgfortran/libquadmath. An image layer stores a hard
  link once.

usage: python slim.py SITE_PACKAGES
"""
import hashlib, os, shutil, sys
root = sys.argv[1]
removed = 0
def rm(p):
    global removed
    for d, _, fs in os.walk(p):
        removed += sum(os.lstat(os.path.join(d, f)).st_size for f in fs)
    shutil.rmtree(p)
for d, dirs, _ in os.walk(root):
    for name in list(dirs):
        p = os.path.join(d, name)
        rel = os.path.relpath(p, root)
        if name == "tests" or rel in ("casadi/include",):
            rm(p); dirs.remove(name)
seen, linked = {}, 0
for d, _, fs in os.walk(root):
    for f in sorted(fs):
        p = os.path.join(d, f)
        st = os.lstat(p)
        if not os.path.isfile(p) or os.path.islink(p) or st.st_size < 4096:
            continue
        with open(p, "rb") as fh:
            h = (st.st_size, hashlib.sha256(fh.read()).digest())
        if h in seen and os.lstat(seen[h]).st_mode == st.st_mode:
            os.unlink(p); os.link(seen[h], p); linked += st.st_size
        else:
            seen.setdefault(h, p)
print(f"removed {removed/2**20:.0f} MiB, hard-linked {linked/2**20:.0f} MiB of duplicates")
