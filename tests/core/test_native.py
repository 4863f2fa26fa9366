"""excite.core.native: a compiler that does not finish is ended, and no build is left half done."""

from __future__ import annotations

import time

import pytest

from excite.core import native, processes



def test_a_compiler_that_hangs_is_ended_at_the_limit_with_a_one_line_error(tmp_path, monkeypatch):
    pid_file = tmp_path / "pid"
    cc = tmp_path / "cc"
    cc.write_text(f"#!/bin/sh\necho $$ > {pid_file}\nexec sleep 120\n")  # the compiler itself hangs
    cc.chmod(0o755)
    monkeypatch.setenv("CC", str(cc))
    monkeypatch.setattr(native, "COMPILE_TIMEOUT_S", 1.0)
    lib = tmp_path / "cache" / "native" / "_native-test.so"
    t0 = time.monotonic()
    with pytest.raises(ImportError, match=r"did not finish within 1 s") as err:
        native.build(lib)
    assert time.monotonic() - t0 < 30
    assert "\n" not in str(err.value) and str(cc) in str(err.value)
    assert not processes.alive(int(pid_file.read_text()))
    # nothing half built, and no lock holding the next build back
    assert sorted(p.name for p in lib.parent.iterdir()) == []
