"""The generated C header compiles cleanly and agrees with Python over (and beyond) the box."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from test_export_encodings import synthetic_map

from thrustmap.fitting.export.c_header import export_c_header, reference_throttle
from thrustmap.fitting.export.encodings import ExportOptions, target_scale

CC = shutil.which("gcc") or shutil.which("cc")
pytestmark = pytest.mark.skipif(CC is None, reason="no C compiler (gcc/cc) on PATH")

HARNESS = r"""
#include <stdio.h>
#include "thrustmap.h"
int main(void)
{
    float t, b;
    while (scanf("%f %f", &t, &b) == 2) printf("%.9g\n", (double)thrustmap_throttle(t, b));
    return 0;
}
"""


def _grid() -> tuple[np.ndarray, np.ndarray]:
    # over the box and beyond it on every side (clamping), float32 like the C entry point
    t, b = np.meshgrid(np.linspace(-1.0, 12.0, 53), np.linspace(19.0, 26.5, 16))
    return t.ravel().astype(np.float32), b.ravel().astype(np.float32)


def _compile_and_run(header: str, tmp: Path, *, use_float: bool) -> np.ndarray:
    assert CC is not None
    (tmp / "thrustmap.h").write_text(header)
    (tmp / "main.c").write_text(HARNESS)
    exe = tmp / ("h_float" if use_float else "h_double")
    flags = ["-DTHRUSTMAP_USE_FLOAT"] if use_float else []
    subprocess.run(
        [CC, "-std=c99", "-O2", "-Wall", "-Wextra", "-Werror", "-pedantic", *flags,
         "-o", str(exe), str(tmp / "main.c"), "-lm"],
        check=True, capture_output=True, text=True,
    )  # fmt: skip
    t, b = _grid()
    stdin = "".join(f"{float(x)!r} {float(y)!r}\n" for x, y in zip(t, b, strict=True))
    out = subprocess.run([str(exe)], input=stdin, check=True, capture_output=True, text=True)
    return np.array([float(v) for v in out.stdout.split()])


@pytest.mark.parametrize(
    ("model", "gamma", "encoding", "range_"),
    [
        ("poly2", False, "percent", None),
        ("poly3", True, "pwm", None),
        ("poly4", False, "dshot", None),
        ("poly3-trunc", True, "crazyflie-cmd", None),
        ("motor", True, "pwm", (1100.0, 1940.0)),
        ("la", False, "norm-sym", None),
        ("linear", False, "oneshot125", None),
    ],
)
def test_compiled_header_matches_python(
    tmp_path: Path, model: str, gamma: bool, encoding: str, range_: tuple[float, float] | None
) -> None:
    tmap = synthetic_map(model, gamma)
    # through the header export itself: export_map refuses the 6S map in Crazyflie units
    res = export_c_header(tmap, ExportOptions(encoding=encoding, range_=range_))
    assert "float thrustmap_throttle(float thrust_n, float voltage_v)" in res.text
    scale = target_scale(encoding, range_)
    t, b = _grid()
    expected = reference_throttle(tmap, scale, t.astype(float), b.astype(float))
    got_double = _compile_and_run(res.text, tmp_path, use_float=False)
    got_float = _compile_and_run(res.text, tmp_path, use_float=True)
    # double arithmetic: the only error left is the float return value (half an ulp)
    ulp = np.spacing(np.abs(expected).astype(np.float32)).astype(float)
    assert np.all(np.abs(got_double - expected) <= ulp + 1e-12 * scale.span)
    # float32 arithmetic on the re-centred polynomial: measured <= 2.8e-7 of the range
    assert np.max(np.abs(got_float - expected)) / scale.span < 1e-6
    # clamping: outside the box the output is the box-edge value, and never leaves the range
    assert got_double.min() >= scale.lo and got_double.max() <= scale.hi


def test_raw_monomials_in_float_would_fail() -> None:
    """Why the header re-centres: the raw poly4 evaluated in float32 at 25 V loses digits."""
    tmap = synthetic_map("poly4")
    t, b = _grid()
    tt, bb = np.clip(t, 0.3, 10.0), np.clip(b, 21.0, 25.2)
    from thrustmap.fitting.models import MODELS

    powers = MODELS["poly4"].powers  # type: ignore[attr-defined]
    acc = np.zeros_like(tt)
    for (i, j), c in zip(powers, tmap.coefficients, strict=True):
        acc = (acc + np.float32(c) * tt ** np.float32(i) * bb ** np.float32(j)).astype(np.float32)
    exact = tmap.throttle_pct(tt.astype(float), bb.astype(float))
    raw_err = float(np.max(np.abs(acc - exact)) / 100.0)
    assert raw_err > 3e-6  # measured 1e-5: >10x what the re-centred float header achieves
