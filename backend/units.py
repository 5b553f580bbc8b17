"""The lab's units in Python: what a person reads in a report, in the system the lab chose (``lab``: mm, kN, kN/mm,
bar; ``si``: m, N, N/m, MPa). The service speaks SI throughout; only what is printed is converted here.

The definitions and the number formatting mirror the console's one place, frontend/static/js/units.js (its
QUANTITIES, ``fmt``, ``fmtU``, ``sigDigits``): a value reads the same in a report as on the console.
tests/backend/test_units.py reads units.js and holds the two to the same table and the same digits.

    Units("lab").text("stiffness", 6.8e5)   # '0.68 kN/mm'
    Units("si").text("stiffness", 6.8e5)    # '680000 N/m'
"""

from __future__ import annotations

import math
import re
from decimal import ROUND_HALF_UP, Decimal

SYSTEMS = ("lab", "si")

# quantity -> {system: (unit, factor from SI)} and the resolution (SI: sets the decimals) or significant digits
QUANTITIES: dict[str, dict] = {
    "length": {"lab": ("mm", 1e3), "si": ("m", 1), "res": 1e-5},
    "force": {"lab": ("kN", 1e-3), "si": ("N", 1), "res": 10},
    "stiffness": {"lab": ("kN/mm", 1e-6), "si": ("N/m", 1), "sig": 4},
    "velocity": {"lab": ("mm/s", 1e3), "si": ("m/s", 1), "res": 1e-4},
    "pressure": {"lab": ("bar", 1e-5), "si": ("MPa", 1e-6), "res": 1e4},
    "energy": {"lab": ("J", 1), "si": ("J", 1), "sig": 4},
    "inverse_length": {"lab": ("1/mm", 1e-3), "si": ("1/m", 1), "sig": 4},
    "flow": {"lab": ("l/min", 6e4), "si": ("m3/s", 1), "sig": 4},
    "voltage": {"lab": ("V", 1), "si": ("V", 1), "res": 1e-3},
    "frequency": {"lab": ("Hz", 1), "si": ("Hz", 1), "sig": 4},
    "time": {"lab": ("s", 1), "si": ("s", 1), "sig": 4},
    "ratio": {"lab": ("-", 1), "si": ("-", 1), "sig": 4},
    "percent": {"lab": ("%", 100), "si": ("%", 100), "res": 1e-4},
    "angle": {"lab": ("deg", 1), "si": ("deg", 1), "res": 0.01},
    "mass": {"lab": ("kg", 1), "si": ("kg", 1), "sig": 5},
    "acceleration": {"lab": ("m/s2", 1), "si": ("m/s2", 1), "sig": 3},
}

# an SI unit as sim/ declares it (controller options, adapted parameters) -> the quantity it measures
SI_UNIT_QUANTITIES = {"m": "length", "N": "force", "N/m": "stiffness", "m/s": "velocity", "Pa": "pressure",
                      "1/m": "inverse_length", "m3/s": "flow"}


def _to_fixed(v: float, decimals: int) -> str:
    """JavaScript's Number.prototype.toFixed: the exact binary value rounded half away from zero."""
    return str(Decimal(v).quantize(Decimal(1).scaleb(-decimals), rounding=ROUND_HALF_UP))


def _to_precision(v: float, sig: int) -> float:
    """Number(v.toPrecision(sig)) of JavaScript: ``sig`` significant digits, ties away from zero."""
    if v == 0 or not math.isfinite(v):
        return v
    exponent = Decimal(v).adjusted()
    return float(Decimal(v).quantize(Decimal(1).scaleb(exponent - sig + 1), rounding=ROUND_HALF_UP))


def _to_exponential(v: float, digits: int) -> str:
    """JavaScript's toExponential(digits): '1.235e+9', '-4.000e-5'."""
    d = Decimal(v)
    exponent = d.adjusted()
    mantissa = (d.scaleb(-exponent)).quantize(Decimal(1).scaleb(-digits), rounding=ROUND_HALF_UP)
    if abs(mantissa) >= 10:  # 9.9995 -> 10.00: one more in the exponent
        exponent += 1
        mantissa = (d.scaleb(-exponent)).quantize(Decimal(1).scaleb(-digits), rounding=ROUND_HALF_UP)
    return f"{mantissa}e{'+' if exponent >= 0 else '-'}{abs(exponent)}"


def _no_negative_zero(text: str) -> str:
    return text[1:] if re.fullmatch(r"-0(\.0*)?", text) else text


def sig_digits(v: float, sig: int = 4, trailing_zeros: bool = False) -> str:
    """A number with ``sig`` significant digits, in plain notation between 1e-4 and 1e9 ('883900', '0.0806');
    units.js sigDigits. ``trailing_zeros=True`` keeps them ('1.700', not '1.7': a column of a table)."""
    if not math.isfinite(v):
        return "-"
    if v == 0:
        return "0"
    a = abs(v)
    if a >= 1e9 or a < 1e-4:
        text = _to_exponential(v, sig - 1)
        return text if trailing_zeros else re.sub(r"\.?0+e", "e", text)
    magnitude = math.floor(math.log10(a))
    decimals = max(0, sig - 1 - magnitude)
    text = _to_fixed(_to_precision(v, sig), decimals)
    if trailing_zeros:
        return _no_negative_zero(text)
    text = re.sub(r"(\.\d*?)0+$", r"\1", text)
    return _no_negative_zero(re.sub(r"\.$", "", text))


class Units:
    """The unit system a report is printed in (``lab`` or ``si``; anything else is ``lab``, as in units.js)."""

    def __init__(self, system: str | None = "lab"):
        self.system = "si" if system == "si" else "lab"

    def __repr__(self) -> str:
        return f"Units({self.system!r})"

    @staticmethod
    def _q(quantity: str) -> dict:
        try:
            return QUANTITIES[quantity]
        except KeyError:
            raise ValueError(f"unknown quantity {quantity!r}; known: {', '.join(QUANTITIES)}") from None

    def unit(self, quantity: str) -> str:
        """The display unit ('mm', 'kN', ...)."""
        return self._q(quantity)[self.system][0]

    def factor(self, quantity: str) -> float:
        """SI -> display."""
        return float(self._q(quantity)[self.system][1])

    def value(self, quantity: str, si: float) -> float:
        """The number shown for an SI value (no rounding)."""
        return si * self.factor(quantity)

    def decimals(self, quantity: str) -> int | None:
        """Decimals that fit the quantity's resolution in the display unit (None: significant digits instead)."""
        d = self._q(quantity)
        if "res" not in d:
            return None
        shown = d["res"] * d[self.system][1]
        return max(0, math.ceil(-math.log10(shown) - 1e-9))

    def fmt(self, quantity: str, si, sig: int | None = None, sign: bool = False, trailing_zeros: bool = False) -> str:
        """An SI value in the display unit, without the unit: digits from the resolution (or ``sig`` significant
        digits), never '-0.00'; '-' for a value that is not a finite number (units.js fmt). ``trailing_zeros``
        keeps the zeros of significant digits ('1.700': the columns of a table line up)."""
        if isinstance(si, bool) or not isinstance(si, (int, float)) or not math.isfinite(si):
            return "-"
        v = self.value(quantity, float(si))
        dec = None if sig or abs(v) >= 1e21 else self.decimals(quantity)  # toFixed's own limit
        text = sig_digits(v, sig or self._q(quantity).get("sig") or 4, trailing_zeros) if dec is None else \
            _no_negative_zero(_to_fixed(v, dec))
        if sign and v > 0 and float(text) != 0:
            text = "+" + text
        return text

    def text(self, quantity: str, si, sig: int | None = None, sign: bool = False) -> str:
        """fmt() followed by the unit: '30.00 mm', '26.61 kN' (units.js fmtU)."""
        shown = self.fmt(quantity, si, sig=sig, sign=sign)
        if shown == "-":
            return "-"
        unit = self.unit(quantity)
        return shown if unit == "-" else f"{shown} {unit}"

    def si_unit_text(self, value, si_unit: str | None, sig: int = 4) -> str:
        """A value sim/ declares in an SI unit ('N/m', 'm', ...) in the display unit when it is one of the lab's
        quantities, else as declared (``sig`` significant digits, the unit after it unless '-')."""
        quantity = SI_UNIT_QUANTITIES.get(si_unit or "")
        if quantity is not None:
            return self.text(quantity, value, sig=sig)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            return str(value)
        shown = sig_digits(float(value), sig)
        return shown if not si_unit or si_unit == "-" else f"{shown} {si_unit}"


LAB = Units("lab")
SI = Units("si")
