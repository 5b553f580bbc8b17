"""backend.units against the console's frontend/static/js/units.js: the same table of quantities (read from the
file) and the same digits for the same values (units.js run in node, when it is installed)."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from backend.units import QUANTITIES, Units, sig_digits

UNITS_JS = Path(__file__).resolve().parents[2] / "frontend" / "static" / "js" / "units.js"


def js_quantities() -> dict:
    """units.js's QUANTITIES as a dict, read from its source (one quantity a line)."""
    text = UNITS_JS.read_text()
    block = re.search(r"const QUANTITIES = \{(.*?)\n\};", text, re.S)
    assert block, "units.js has no QUANTITIES table"
    out = {}
    for m in re.finditer(r"^\s*(\w+): \{ lab: \[\"([^\"]+)\", ([^\]]+)\], si: \[\"([^\"]+)\", ([^\]]+)\], "
                         r"(res|sig): ([^ ]+) \},", block.group(1), re.M):
        name, lab_u, lab_f, si_u, si_f, kind, amount = m.groups()
        out[name] = {"lab": (lab_u, float(lab_f)), "si": (si_u, float(si_f)), kind: float(amount)}
    lines = [ln for ln in block.group(1).splitlines() if re.match(r"^\s*\w+: \{", ln)]
    assert len(out) == len(lines), "a line of QUANTITIES this test cannot read"
    return out


def test_the_quantities_are_those_of_units_js():
    js = js_quantities()
    assert set(js) == set(QUANTITIES)
    for name, d in QUANTITIES.items():
        py = {k: (v[0], float(v[1])) if isinstance(v, tuple) else float(v) for k, v in d.items()}
        assert py == js[name], name


CASES = [("length", v) for v in (0.03, -0.0301234, 1e-6, -1e-7, 0.15, 0.0)] + \
        [("force", v) for v in (26610.4, -125034.7875, 1.2258e6, 4.9, -4.9, 850000.0)] + \
        [("stiffness", v) for v in (6.8e5, 883912.3, 1.029e6, 12.5, 0.0, -3.3e9)] + \
        [("pressure", v) for v in (100e5, 7e6, 1234.5)] + \
        [("velocity", v) for v in (0.1234, -0.05)] + \
        [("energy", v) for v in (1234.567, 0.00001234)] + \
        [("inverse_length", v) for v in (450.0, 2.5e4)] + \
        [("percent", v) for v in (0.1234, 0.05)] + \
        [("voltage", v) for v in (1.23456, -0.0004)] + \
        [("mass", v) for v in (125034.7875,)] + [("acceleration", v) for v in (9.80665,)] + \
        [("ratio", v) for v in (0.0806, 1e-5, 2.5e9)] + [("flow", v) for v in (1.5e-4,)]

NODE_SCRIPT = """
globalThis.window = { addEventListener() {} };
globalThis.localStorage = { getItem() { return null; }, setItem() {} };
const u = await import(process.argv[1]);
const cases = JSON.parse(process.argv[2]);
const out = {};
for (const sys of ["lab", "si"]) {
  u.setSystem(sys);
  out[sys] = cases.map(([q, v]) => [u.fmtU(q, v), u.fmtU(q, v, { sig: 3 }), u.fmt(q, v, { sign: true })]);
}
console.log(JSON.stringify(out));
"""


def test_the_same_values_read_the_same_in_a_report_and_on_the_console():
    node = shutil.which("node")
    if node is None:
        pytest.skip("node is not installed: units.js cannot be run here")
    run = subprocess.run([node, "--input-type=module", "-e", NODE_SCRIPT, UNITS_JS.as_uri(), json.dumps(CASES)],
                         capture_output=True, text=True, timeout=60, check=True)
    js = json.loads(run.stdout)
    for system in ("lab", "si"):
        u = Units(system)
        py = [[u.text(q, v), u.text(q, v, sig=3), u.fmt(q, v, sign=True)] for q, v in CASES]
        assert py == js[system], [(c, a, b) for c, a, b in zip(CASES, py, js[system], strict=True) if a != b]


def test_a_few_readings_by_hand():
    lab, si = Units("lab"), Units("si")
    assert lab.text("stiffness", 6.8e5) == "0.68 kN/mm" and si.text("stiffness", 6.8e5) == "680000 N/m"
    assert lab.text("length", 0.03) == "30.00 mm" and si.text("length", 0.03) == "0.03000 m"
    assert lab.text("force", -4.0) == "0.00 kN"  # never "-0.00"
    assert lab.text("pressure", 100e5) == "100.0 bar" and si.text("pressure", 100e5) == "10.00 MPa"
    assert lab.text("length", float("nan")) == "-" and lab.fmt("force", None) == "-"
    assert Units("anything").system == "lab"
    assert sig_digits(2.5e9, 4) == "2.5e+9" and sig_digits(-0.00004, 4) == "-4e-5"
    # a table's column keeps its zeros (the digits line up); the console's text drops them
    assert lab.fmt("stiffness", 1.7e6, trailing_zeros=True) == "1.700" and lab.fmt("stiffness", 1.7e6) == "1.7"
    assert lab.fmt("energy", 180.0, trailing_zeros=True) == "180.0" and si.fmt("energy", 2.5e9, trailing_zeros=True) \
        == "2.500e+9"
    assert lab.si_unit_text(2.0e5, "N/m") == "0.2 kN/mm" and lab.si_unit_text(0.5, "V/m") == "0.5 V/m"
    with pytest.raises(ValueError, match="unknown quantity"):
        lab.unit("luminance")
