"""Samples of a test: one row per control period, addressed by name (``samples["force_n"]``).

The closed loop (sim.loop) writes one row per control period. Compiled code fills the rows through the
private index constants below; everything else reads them by name through ``Samples``, in the spirit of
python-control's named signals. Fields are append-only: stored records keep their column count, and rows
with fewer columns than ``SAMPLE_FIELDS`` read the missing ones as NaN.

Fields (SI units):

- ``time_s``: start of the control period (test time).
- ``target_m``, ``model_m``: the target r and the reference model output y_m (eq. 8); NaN in open-loop rows.
- ``displacement_m``: the table displacement. In simulation the true one; from a real rig, its sensor reading.
- ``voltage_v``: the valve command applied over the period (after saturation).
- ``force_n``: the isolator force.
- ``load_pressure_pa``: the load pressure P_L as measured (the pressure sensor's reading).
- ``ar_hat``, ``ay_hat``, ``as_hat``: what the controller adapts (labels per controller in sim.controllers).
- ``velocity_m_per_s``, ``flow_m3_per_s``, ``valve_v``: plant states a simulation knows (NaN from a real rig).
- ``command_raw_v``: the controller's command before saturation.
- ``measured_displacement_m``: the position sensor's reading, what the controller saw.
- ``supply_pressure_pa``: the supply pressure as measured.
- ``flags``: status bits of the period (``sim.measurement`` STATUS_* from the rig, FLAG_* from the loop).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import numpy as np

CSV_FIELDS = ("time_s", "target_m", "model_m", "displacement_m", "voltage_v", "force_n", "load_pressure_pa",
              "ar_hat", "ay_hat", "as_hat")
SAMPLE_FIELDS = CSV_FIELDS + ("velocity_m_per_s", "flow_m3_per_s", "command_raw_v", "valve_v",
                              "measured_displacement_m", "supply_pressure_pa", "flags")
#: what ``isorig simulate`` and ``data.csv`` write: the ten paper-era columns, then the sensor reading and flags
RECORD_FIELDS = CSV_FIELDS + ("measured_displacement_m", "flags")
N_FIELDS = len(SAMPLE_FIELDS)
FIELD_INDEX = {name: i for i, name in enumerate(SAMPLE_FIELDS)}

# Column indices for compiled code only (sim.loop, sim.plant); read rows by name everywhere else.
(_TIME, _TARGET, _MODEL, _Y, _U, _FORCE, _PL, _AR, _AY, _AS, _VEL, _FLOW, _URAW, _VALVE, _YMEAS, _PS,
 _FLAGS) = range(N_FIELDS)


def check_stored_width(n_columns: int) -> None:
    """Refuse stored rows wider than the fields this version knows (a record from a newer isorig)."""
    if n_columns > N_FIELDS:
        raise ValueError(f"stored rows have {n_columns} columns, more than the {N_FIELDS} known fields")


class Samples:
    """Rows of a test addressed by field name; a thin view over an (n, len(fields)) float array.

    ``s["force_n"]`` is a column (a view), ``s[rows]`` (slice, index array or boolean mask) is a ``Samples``
    of those rows, ``s.array`` the 2-D array, ``len(s)`` the number of rows.
    """

    __slots__ = ("array", "fields", "_index")

    def __init__(self, array: np.ndarray, fields: Sequence[str] = SAMPLE_FIELDS):
        array = np.asarray(array, dtype=np.float64)
        if array.ndim != 2 or array.shape[1] != len(fields):
            raise ValueError(f"samples need shape (n, {len(fields)}) for fields {tuple(fields)}, got {array.shape}")
        self.array = array
        self.fields = tuple(fields)
        self._index = FIELD_INDEX if self.fields == SAMPLE_FIELDS else {f: i for i, f in enumerate(self.fields)}

    @classmethod
    def empty(cls, n_rows: int = 0) -> Samples:
        """n rows of NaN in the full layout."""
        return cls(np.full((n_rows, N_FIELDS), np.nan))

    @classmethod
    def from_stored(cls, array: np.ndarray) -> Samples:
        """Rows stored with the first k fields (an older record): the later fields read as NaN."""
        array = np.asarray(array, dtype=np.float64)
        check_stored_width(array.shape[1])
        if array.shape[1] < N_FIELDS:
            full = np.full((array.shape[0], N_FIELDS), np.nan)
            full[:, : array.shape[1]] = array
            array = full
        return cls(array)

    @classmethod
    def concatenate(cls, parts: Iterable[Samples]) -> Samples:
        parts = [p for p in parts if len(p)]
        if not parts:
            return cls.empty()
        return cls(np.concatenate([p.array for p in parts]), parts[0].fields)

    def __len__(self) -> int:
        return self.array.shape[0]

    @property
    def shape(self) -> tuple[int, int]:
        return self.array.shape

    def __getitem__(self, key):
        if isinstance(key, str):
            try:
                return self.array[:, self._index[key]]
            except KeyError:
                raise KeyError(f"no field {key!r}; fields: {', '.join(self.fields)}") from None
        if isinstance(key, tuple):
            raise TypeError("address a column by its name, e.g. samples['force_n'][rows], not samples[rows, j]")
        return Samples(self.array[key].reshape(-1, len(self.fields)), self.fields)

    def __setitem__(self, key: str, value) -> None:
        self.array[:, self._index[key]] = value

    def select(self, names: Sequence[str]) -> np.ndarray:
        """The named columns as an (n, len(names)) array, in that order."""
        return self.array[:, [self._index[n] for n in names]]

    def row(self, i: int) -> dict:
        """One row as {field: value}."""
        return dict(zip(self.fields, self.array[i].tolist(), strict=True))

    def __repr__(self) -> str:
        return f"Samples({len(self)} rows x {len(self.fields)} fields)"
