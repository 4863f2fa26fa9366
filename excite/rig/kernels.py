"""The kernels compiled with the package: those of every registered measurement kind, for every
variant that the example rigs below use (the bundled rigs, and the variants they leave out),
generated from the kinds' statements by :mod:`excite.factors.generate` into
``excite/factors/generated.c``.

    python -m excite.rig.kernels          # rewrite excite/factors/generated.c
    python -m excite.rig.kernels --check  # exit 1 if it differs from what the statements give

A kind added to excite is covered by adding a rig that has it to :data:`EXAMPLES` (the tests say
so when it is missing).
"""

from __future__ import annotations

import argparse
import copy
import sys

import yaml

from ..factors import generate
from ..factors.generate import Spec
from .config import RIGS_DIR, Rig, build_rig

_GNSS = {"name": "gnss", "kind": "gnss", "rate_hz": 10.0, "T_B_S": {"translation_m": [0.4, -0.3, 1.6]},
         "noise": {"horizontal_sigma_m": 0.02, "vertical_sigma_m": 0.05, "correlation_time_s": 3.0}}
_RADAR_2D = {"name": "radar_corner", "kind": "radar", "rate_hz": 10, "dimensions": 2,
             "T_B_S": {"translation_m": [2.0, 0.8, 0.1], "rpy_deg": [1.0, 2.0, 60.0]},
             "noise": {"doppler_sigma_mps": 0.1, "stationary_targets": 4}}


def _bundled(name: str) -> dict:
    return yaml.safe_load((RIGS_DIR / f"{name}.yaml").read_text())


def _with(name: str, change) -> dict:
    data = copy.deepcopy(_bundled(name))
    change(data)
    return data


def _no_steering(data: dict) -> None:
    data["ackermann"].pop("steering", None)
    data["targets"] = {k: v for k, v in data["targets"].items() if not k.startswith("steering.")}


def _radps(data: dict) -> None:
    data["ackermann"].update(speeds="radps", radius_m=0.33)
    data["targets"] = {("wheel.radius_*" if k == "wheel.scale_*" else k): ("0.3 mm" if k == "wheel.scale_*" else v)
                       for k, v in data["targets"].items()}


# The rigs whose entries the kernels are generated for: between them every variant of every
# built-in kind (a GNSS antenna; CAN wheel speeds in m/s and rad/s, with and without steering; a
# 2-D and a 3-D radar).
EXAMPLES = {
    "robotaxi": lambda: _with("robotaxi", lambda d: d["sensors"].append(dict(_GNSS))),
    "sedan": lambda: _with("sedan", lambda d: d["sensors"].append(dict(_RADAR_2D))),
    "sedan, no steering, rad/s": lambda: _with("sedan", lambda d: (_no_steering(d), _radps(d))),
    "sedan, no steering": lambda: _with("sedan", _no_steering),
    "sedan, rad/s": lambda: _with("sedan", _radps),
}




def rigs() -> list[Rig]:
    """The example rigs, built."""
    return [build_rig(data()) for data in EXAMPLES.values()]


def specs() -> dict[str, Spec]:
    """Every kernel compiled with the package (:func:`excite.factors.generate.specs_of` of the
    example rigs)."""
    return generate.specs_of(rigs())


def source() -> str:
    """The C source of every kernel compiled with the package, with their table."""
    return generate.source(specs())


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Generate excite/factors/generated.c from the kinds' statements.")
    parser.add_argument("--check", action="store_true", help="exit 1 if the file differs from what is generated")
    args = parser.parse_args(argv)
    text = source()
    target = generate.TARGET
    if args.check:
        same = target.exists() and target.read_text() == text
        print(f"{target}: {'up to date' if same else 'differs from what the statements give'}")
        return 0 if same else 1
    target.write_text(text)
    print(f"wrote {target} ({len(text) // 1024} KiB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
