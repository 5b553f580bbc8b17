"""Campaigns on a distributed engine: the comparison grid, the robust corners, the ablations and Monte Carlo
campaigns over the rig and the isolator, run on ``dask.distributed``.

The engine (``Engine``) is a local cluster of worker processes by default, or a lab's existing cluster
(``Engine(scheduler="tcp://host:8786")``). Each task runs a chunk of points and returns their comparison rows
(``sim.compare.point_figures``), computed in the worker: a run's samples (1-5 MB) never travel. The numbers
are those of ``sim.compare.run_grid`` (``sim.engine.run_batch``'s process pool) to the last bit: the same
engine, the same scenarios, the same figures; tests/test_campaign.py checks it.

A Monte Carlo campaign comes from a file (JSON or TOML; docs/compare.md, "Campaigns"): distributions for
named rig parameters (``RigParameters`` field names, SI) and isolator parameters (``ISOLATOR_PARAMETERS``),
drawn for the simulated PLANT only (``Scenario.plant_changes``): the controller keeps the nominal rig. The
draws are made here, up front, from the file's seed: the same file gives the same runs on any engine and
any number of workers.

Draws outside a parameter's allowed range (``RigParameters`` field metadata min/max, ``sim.isolator.LIMITS``):
a distribution that puts more than ``MAX_OUTSIDE_SHARE`` (1 %) of its mass outside the range is refused up
front, with the share; a uniform distribution or a fixed value must lie inside it. The rare draws outside
the range that a distribution within the limit still makes are drawn again (the distribution is truncated
to the range), and counted. A run whose draws together cannot be a rig (a dead zone as wide as the command
range ...) is drawn again too; when more than 1 % of the runs needed that, the campaign is refused.
"""

from __future__ import annotations

import csv
import functools
import logging
import math
import os
import time
from concurrent.futures import CancelledError
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np

from ._numba_cache import source_fingerprint
from .compare import (
    CYCLES,
    TAPER_CYCLES,
    TARGETS,
    GridPoint,
    limit_cycle,
    meets_targets,
    point_figures,
    run_grid,
    run_point,
)
from .datafile import load_mapping
from .engine import ISOLATOR_PARAMETERS, Scenario, warm_up
from .errors import FieldError
from .isolator import LIMITS, Isolator, IsolatorError, load_isolator
from .rig import DEFAULT_RIG, RigError, RigParameters
from .rigfile import RIG_FIELDS, rig_from_mapping, suggestion

SOURCES_AT_IMPORT = source_fingerprint()  # the code this process runs: a cluster's workers must run the same
MAX_OUTSIDE_SHARE = 0.01  # a distribution may put at most this share of its draws outside the allowed range
MAX_RUNS = 100_000
MAX_CYCLES = 1000
SCHEDULER_TIMEOUT_S = 5.0
DISTRIBUTIONS = {"normal": ("mean", "std"), "uniform": ("low", "high"), "lognormal": ("median", "sigma"),
                 "loguniform": ("low", "high")}
FIGURE_FORMATS = (".png", ".svg", ".pdf")
CAMPAIGN_KEYS = ("name", "description", "runs", "seed", "controller", "isolator", "supply_bar", "amplitude_m",
                 "frequency_hz", "cycles", "nominal_rig", "rig", "isolator_parameters", "commissioning")
COMMISSIONING_KEYS = ("more_tests", "max_stroke_m", "max_velocity_m_per_s", "vertical_load_n")


class CampaignError(FieldError):
    """A campaign file that cannot be run, a scheduler that does not answer, outputs that cannot be written."""


# ---------------------------------------------------------------------------------------------------------------
# distributions


def _normal_cdf(z: float) -> float:
    return 0.5 * (1.0 + math.erf(z / math.sqrt(2.0)))


@dataclass(frozen=True)
class Distribution:
    """One parameter's distribution: ``fixed`` (a), ``normal`` (mean a, std b), ``uniform`` (low a, high b),
    ``lognormal`` (median a, sigma b of ln x), ``loguniform`` (low a, high b: ln x uniform)."""

    kind: str
    a: float
    b: float = 0.0

    def draw(self, rng: np.random.Generator) -> float:
        if self.kind == "normal":
            return float(rng.normal(self.a, self.b))
        if self.kind == "uniform":
            return float(rng.uniform(self.a, self.b))
        if self.kind == "lognormal":
            return float(rng.lognormal(math.log(self.a), self.b))
        if self.kind == "loguniform":
            return float(math.exp(rng.uniform(math.log(self.a), math.log(self.b))))
        return self.a

    def share_outside(self, lo: float, hi: float) -> float:
        """The probability of a draw outside [lo, hi]."""
        if self.kind == "normal":
            below = _normal_cdf((lo - self.a) / self.b) if math.isfinite(lo) else 0.0
            above = 1.0 - _normal_cdf((hi - self.a) / self.b) if math.isfinite(hi) else 0.0
            return below + above
        if self.kind == "lognormal":
            below = _normal_cdf((math.log(lo) - math.log(self.a)) / self.b) if lo > 0.0 else 0.0
            above = 1.0 - _normal_cdf((math.log(hi) - math.log(self.a)) / self.b) if math.isfinite(hi) else 0.0
            return below + above
        low, high = (self.a, self.b) if self.kind in ("uniform", "loguniform") else (self.a, self.a)
        return 0.0 if lo <= low and high <= hi else 1.0

    def to_dict(self) -> dict:
        if self.kind == "fixed":
            return {"fixed": self.a}
        return {self.kind: dict(zip(DISTRIBUTIONS[self.kind], (self.a, self.b), strict=True))}

    def describe(self) -> str:
        if self.kind == "fixed":
            return f"{self.a:g}"
        names = DISTRIBUTIONS[self.kind]
        return f"{self.kind}({names[0]} {self.a:g}, {names[1]} {self.b:g})"


def parameter_range(name: str) -> tuple[float, float, str]:
    """(min, max, unit) a rig or isolator parameter may take."""
    if name in ISOLATOR_PARAMETERS:
        return LIMITS[name]
    meta = next(f.metadata for f in fields(RigParameters) if f.name == name)
    return meta["min"], meta["max"], meta["unit"]


def _number(where: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise CampaignError(where, value, "a number", f"{where} = {value!r} is not a number")
    if not math.isfinite(value):
        raise CampaignError(where, value, "a finite number", f"{where} = {value!r} is not a finite number")
    return float(value)


def parse_distribution(where: str, name: str, spec) -> Distribution:
    """A distribution from the file (a number, or {"normal": [mean, std]} ...), checked against the range of
    parameter ``name``."""
    lo, hi, unit = parameter_range(name)
    allowed = f"[{lo:g}, {hi:g}] {unit}"
    if isinstance(spec, (int, float)) and not isinstance(spec, bool):
        dist = Distribution("fixed", _number(where, spec))
        if dist.share_outside(lo, hi) > 0.0:
            raise CampaignError(name, spec, allowed, f"{where} = {spec:g} {unit} is outside the allowed range "
                                f"{allowed}")
        return dist
    shape = ('a number (a fixed value) or one distribution: {"normal": [mean, std]}, {"uniform": [low, high]}, '
             '{"lognormal": [median, sigma]} or {"loguniform": [low, high]}')
    if not isinstance(spec, dict) or len(spec) != 1:
        raise CampaignError(name, spec, shape, f"{where} = {spec!r} is not {shape}")
    kind, args = next(iter(spec.items()))
    if kind not in DISTRIBUTIONS:
        raise CampaignError(name, kind, ", ".join(DISTRIBUTIONS), f"{where}: unknown distribution {kind!r}"
                            f"{suggestion(str(kind), tuple(DISTRIBUTIONS))}; allowed: {', '.join(DISTRIBUTIONS)}")
    names = DISTRIBUTIONS[kind]
    if isinstance(args, dict):
        if sorted(args) != sorted(names):
            raise CampaignError(name, args, f"{{{', '.join(names)}}}", f"{where}.{kind} = {args!r}: give "
                                f"exactly {' and '.join(names)}")
        args = [args[n] for n in names]
    if not isinstance(args, (list, tuple)) or len(args) != 2:
        raise CampaignError(name, args, f"[{', '.join(names)}]", f"{where}.{kind} = {args!r} is not "
                            f"[{', '.join(names)}]")
    a, b = (_number(f"{where}.{kind}.{n}", v) for n, v in zip(names, args, strict=True))
    if kind == "normal" and b <= 0.0:
        raise CampaignError(name, b, "std > 0", f"{where}.normal: std = {b:g} {unit} is "
                            f"{'negative' if b < 0 else 'zero'}; a standard deviation must be > 0 (a plain "
                            "number gives a fixed value)")
    if kind in ("uniform", "loguniform") and not a < b:
        raise CampaignError(name, [a, b], "low < high", f"{where}.{kind}: low = {a:g} is not below high = "
                            f"{b:g} {unit}")
    if kind == "loguniform" and a <= 0.0:
        raise CampaignError(name, [a, b], "low > 0", f"{where}.loguniform: low = {a:g} {unit} must be > 0")
    if kind == "lognormal" and (a <= 0.0 or b <= 0.0):
        raise CampaignError(name, [a, b], "median > 0 and sigma > 0", f"{where}.lognormal: median = {a:g} "
                            f"{unit} and sigma = {b:g} (of ln x) must both be > 0")
    dist = Distribution(kind, a, b)
    share = dist.share_outside(lo, hi)
    if kind in ("uniform", "loguniform") and share > 0.0:
        raise CampaignError(name, [a, b], allowed, f"{where}.{kind}: [{a:g}, {b:g}] {unit} leaves the allowed "
                            f"range {allowed}")
    if share > MAX_OUTSIDE_SHARE:
        raise CampaignError(name, spec, allowed, f"{where}: {dist.describe()} {unit} puts {100 * share:.2g} % "
                            f"of its draws outside the allowed range {allowed}; at most "
                            f"{100 * MAX_OUTSIDE_SHARE:g} % may be (those are drawn again)")
    return dist


# ---------------------------------------------------------------------------------------------------------------
# the campaign file


@dataclass
class CampaignPoint(GridPoint):
    """One Monte Carlo run of one controller: the grid point's test on a drawn plant."""

    run: int = 0
    plant: dict = field(default_factory=dict)
    isolator_def: Isolator | None = None
    nominal_rig: RigParameters = DEFAULT_RIG
    noise_seed: int = 0

    def scenario(self, cycles: int = CYCLES) -> Scenario:
        s = Scenario.sine(self.isolator_def, self.supply_bar, self.amplitude_m, self.frequency_hz, cycles,
                          controller=self.controller, taper_cycles=TAPER_CYCLES,
                          controller_options=dict(self.options or {}), rig=self.nominal_rig,
                          plant_changes=dict(self.plant), noise_seed=self.noise_seed)
        s.label = self.label
        return s


@dataclass
class Campaign:
    """A Monte Carlo campaign: one test, ``runs`` plants drawn from the distributions, each controller on each."""

    runs: int
    seed: int
    controllers: tuple[str, ...]
    isolator: Isolator
    supply_bar: float
    amplitude_m: float
    frequency_hz: float
    cycles: int
    distributions: dict[str, Distribution]  # rig and isolator parameters of the plant, by name
    nominal_rig: RigParameters = DEFAULT_RIG
    name: str = ""
    description: str = ""
    source: str = ""
    #: filled by ``points()``: draws made again (per parameter: out of its range; "inconsistent": whole runs)
    redrawn: dict = field(default_factory=dict)
    #: a commissioning campaign (sim.commission.campaign): each drawn rig is commissioned, then tested with
    #: and without its rig file; {"more_tests": [(amplitude_m, frequency_hz), ...], "max_stroke_m",
    #: "max_velocity_m_per_s", "vertical_load_n"}; None: a controller campaign
    commissioning: dict | None = None

    def nominal_scenario(self, controller: str) -> Scenario:
        return CampaignPoint(controller, self.isolator.name, self.supply_bar, self.frequency_hz, self.amplitude_m,
                             "nominal", "nominal", isolator_def=self.isolator,
                             nominal_rig=self.nominal_rig).scenario(self.cycles)

    def draws(self) -> list[tuple[dict, int]]:
        """(plant parameters by name, sensor-noise seed) of every run, from the seed. Draws outside a parameter's
        range are drawn again; so are runs whose draws together cannot be a rig (``CampaignError`` when more
        than 1 % of the runs needed it). Fills ``redrawn``."""
        param_seq, noise_seq = np.random.SeedSequence(self.seed).spawn(2)
        rng = np.random.default_rng(param_seq)
        names = sorted(self.distributions)
        ranges = {n: parameter_range(n)[:2] for n in names}
        redrawn = dict.fromkeys(names, 0)
        inconsistent = 0
        problem = ""
        probe = self.nominal_scenario(self.controllers[0])
        out = []
        for _ in range(self.runs):
            for _attempt in range(100):
                values = {}
                for n in names:
                    lo, hi = ranges[n]
                    x = self.distributions[n].draw(rng)
                    while not lo <= x <= hi:  # at most 1 % of the mass: ends
                        redrawn[n] += 1
                        x = self.distributions[n].draw(rng)
                    values[n] = x
                probe.plant_changes = values
                try:
                    probe.check_plant()
                    break
                except (FieldError, IsolatorError) as exc:
                    inconsistent += 1
                    problem = problem or str(exc)
            else:
                break
            out.append(values)
        self.redrawn = {**redrawn, "inconsistent": inconsistent}
        if len(out) < self.runs or inconsistent > MAX_OUTSIDE_SHARE * (self.runs + inconsistent):
            share = inconsistent / (len(out) + inconsistent)
            raise CampaignError("rig", problem, "draws that make a rig", f"{self.where}: {100 * share:.2g} % of "
                                f"the drawn plants cannot be a rig (at most {100 * MAX_OUTSIDE_SHARE:g} % may be: "
                                f"those are drawn again); the first: {problem}")
        noise_seeds = np.random.default_rng(noise_seq).integers(0, 2 ** 31, size=self.runs)
        return [(values, int(seed)) for values, seed in zip(out, noise_seeds, strict=True)]

    @property
    def where(self) -> str:
        return f"campaign file {self.source}" if self.source else "campaign"

    def points(self) -> list[CampaignPoint]:
        """Every run of every controller (run-major: the controllers on the same plant one after the other),
        each nominal test validated first."""
        for c in self.controllers:
            try:
                self.nominal_scenario(c).validate()
            except (FieldError, IsolatorError) as exc:
                raise CampaignError("test", None, "a test within the rig's envelope", f"{self.where}: {exc}") \
                    from None
        points = []
        for run, (values, noise_seed) in enumerate(self.draws()):
            for c in self.controllers:
                points.append(CampaignPoint(c, self.isolator.name, self.supply_bar, self.frequency_hz,
                                            self.amplitude_m, "drawn", f"run {run}", None, run=run,
                                            plant=dict(values), isolator_def=self.isolator,
                                            nominal_rig=self.nominal_rig, noise_seed=noise_seed))
        return points

    def describe(self) -> dict:
        nominal = {f.name: getattr(self.nominal_rig, f.name) for f in fields(RigParameters)
                   if getattr(self.nominal_rig, f.name) != getattr(DEFAULT_RIG, f.name)}
        return {
            "name": self.name, "description": self.description, "source": self.source, "runs": self.runs,
            "seed": self.seed, "controllers": list(self.controllers), "isolator": self.isolator.to_dict(),
            "supply_bar": self.supply_bar, "amplitude_m": self.amplitude_m, "frequency_hz": self.frequency_hz,
            "cycles": self.cycles, "taper_cycles": TAPER_CYCLES, "nominal_rig_changes": nominal,
            "plant_distributions": {n: d.to_dict() for n, d in sorted(self.distributions.items())},
            "max_outside_share": MAX_OUTSIDE_SHARE, "redrawn": dict(self.redrawn),
        }


def _whole(where: str, value, lo: int, hi: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise CampaignError(where, value, "a whole number", f"{where} = {value!r} is not a whole number")
    if not lo <= value <= hi:
        raise CampaignError(where, value, f"[{lo}, {hi}]", f"{where} = {value} is outside [{lo}, {hi}]")
    return value


def campaign_from_mapping(data, source: str = "", base_dir: Path | None = None) -> Campaign:
    """A campaign from a parsed file, every value checked; one ``CampaignError`` naming the first problem."""
    from .controllers import CONTROLLER_NAMES

    where = f"campaign file {source}" if source else "campaign"
    if not isinstance(data, dict):
        raise CampaignError("campaign", data, "an object", f"{where}: not an object of keys and values")
    for key in data:
        if key not in CAMPAIGN_KEYS:
            raise CampaignError(key, data[key], ", ".join(CAMPAIGN_KEYS), f"{where}: unknown key {key!r}"
                                f"{suggestion(str(key), CAMPAIGN_KEYS)}; allowed: {', '.join(CAMPAIGN_KEYS)}")
    for key in ("runs", "isolator", "supply_bar", "amplitude_m", "frequency_hz"):
        if key not in data:
            raise CampaignError(key, None, "required", f"{where}: {key!r} is missing (required: runs, isolator, "
                                "supply_bar, amplitude_m, frequency_hz)")
    runs = _whole(f"{where}: runs", data["runs"], 1, MAX_RUNS)
    seed = _whole(f"{where}: seed", data.get("seed", 0), 0, 2 ** 63 - 1)
    cycles = _whole(f"{where}: cycles", data.get("cycles", CYCLES), 2 * TAPER_CYCLES + 2, MAX_CYCLES)
    controllers = data.get("controller", ["servo"])
    if isinstance(controllers, str):
        controllers = [controllers]
    if not isinstance(controllers, list) or not controllers or not all(isinstance(c, str) for c in controllers):
        raise CampaignError("controller", controllers, "a controller name or a list of them", f"{where}: "
                            f"controller = {controllers!r} is not a controller name or a non-empty list of them")
    for c in controllers:
        if c not in CONTROLLER_NAMES:
            raise CampaignError("controller", c, ", ".join(CONTROLLER_NAMES), f"{where}: unknown controller "
                                f"{c!r}{suggestion(c, CONTROLLER_NAMES)}; allowed: {', '.join(CONTROLLER_NAMES)}")
    if len(set(controllers)) != len(controllers):
        raise CampaignError("controller", controllers, "each once", f"{where}: a controller is named twice")
    iso_spec = data["isolator"]
    if not isinstance(iso_spec, str) or not iso_spec:
        raise CampaignError("isolator", iso_spec, "a preset name or a .json file", f"{where}: isolator = "
                            f"{iso_spec!r} is not a preset name or the path of an isolator .json file")
    if base_dir is not None and iso_spec.endswith(".json") and not Path(iso_spec).is_absolute():
        iso_spec = str(base_dir / iso_spec)
    try:
        isolator = load_isolator(iso_spec)
    except IsolatorError as exc:
        raise CampaignError("isolator", iso_spec, "a preset or a valid isolator file", f"{where}: {exc}") from None
    supply = _number(f"{where}: supply_bar", data["supply_bar"])
    amplitude = _number(f"{where}: amplitude_m", data["amplitude_m"])
    frequency = _number(f"{where}: frequency_hz", data["frequency_hz"])
    for key, value in (("amplitude_m", amplitude), ("frequency_hz", frequency), ("supply_bar", supply)):
        if value <= 0.0:
            raise CampaignError(key, value, "> 0", f"{where}: {key} = {value:g} must be > 0")
    nominal = DEFAULT_RIG
    if "nominal_rig" in data:
        try:
            nominal = rig_from_mapping(data["nominal_rig"], DEFAULT_RIG, where=f"{where}: nominal_rig")
        except RigError as exc:
            raise CampaignError(exc.field, exc.value, exc.limit, str(exc)) from None
    distributions: dict[str, Distribution] = {}
    for section, allowed, other in (("rig", RIG_FIELDS, ISOLATOR_PARAMETERS),
                                    ("isolator_parameters", ISOLATOR_PARAMETERS, RIG_FIELDS)):
        block = data.get(section, {})
        if not isinstance(block, dict):
            raise CampaignError(section, block, "an object of parameter names and distributions", f"{where}: "
                                f"{section} = {block!r} is not an object of parameter names and distributions")
        for name, spec in block.items():
            if name not in allowed:
                hint = (f" (it is {'an isolator' if section == 'rig' else 'a rig'} parameter: put it under "
                        f"{'isolator_parameters' if section == 'rig' else 'rig'})" if name in other
                        else suggestion(str(name), allowed))
                raise CampaignError(name, spec, ", ".join(allowed), f"{where}: {section}.{name}: {name!r} is not "
                                    f"a{'n isolator' if section != 'rig' else ' rig'} parameter{hint}")
            distributions[name] = parse_distribution(f"{where}: {section}.{name}", name, spec)
    text = {}
    for key in ("name", "description"):
        value = data.get(key, "")
        if not isinstance(value, str):
            raise CampaignError(key, value, "text", f"{where}: {key} must be text")
        text[key] = value[:200]
    commissioning = None
    if "commissioning" in data:
        commissioning = parse_commissioning(f"{where}: commissioning", data["commissioning"])
    return Campaign(runs, seed, tuple(controllers), isolator, supply, amplitude, frequency, cycles, distributions,
                    nominal, text["name"], text["description"], source, commissioning=commissioning)


def parse_commissioning(where: str, spec) -> dict:
    """The commissioning section of a campaign file, every value checked."""
    if not isinstance(spec, dict):
        raise CampaignError("commissioning", spec, "an object", f"{where} must be an object of "
                            f"{', '.join(COMMISSIONING_KEYS)}")
    for key in spec:
        if key not in COMMISSIONING_KEYS:
            raise CampaignError(key, spec[key], ", ".join(COMMISSIONING_KEYS), f"{where}: unknown key {key!r}"
                                f"{suggestion(str(key), COMMISSIONING_KEYS)}; allowed: {', '.join(COMMISSIONING_KEYS)}")
    out = {"more_tests": [], "max_stroke_m": 0.002, "max_velocity_m_per_s": 0.02, "vertical_load_n": None}
    for key in ("max_stroke_m", "max_velocity_m_per_s", "vertical_load_n"):
        if key in spec:
            out[key] = _number(f"{where}.{key}", spec[key])
    tests = spec.get("more_tests", [])
    if not isinstance(tests, list):
        raise CampaignError("more_tests", tests, "a list", f"{where}.more_tests must be a list of "
                            "{amplitude_m, frequency_hz}")
    for i, t in enumerate(tests):
        if not isinstance(t, dict) or sorted(t) != ["amplitude_m", "frequency_hz"]:
            raise CampaignError("more_tests", t, "{amplitude_m, frequency_hz}", f"{where}.more_tests[{i}] = {t!r} "
                                "is not {amplitude_m, frequency_hz}")
        a, f = (_number(f"{where}.more_tests[{i}].{k}", t[k]) for k in ("amplitude_m", "frequency_hz"))
        if a <= 0 or f <= 0:
            raise CampaignError("more_tests", t, "> 0", f"{where}.more_tests[{i}]: amplitude and frequency must be "
                                "> 0")
        out["more_tests"].append((a, f))
    return out


def load_campaign(path: str | Path) -> Campaign:
    """A campaign file (``.toml`` or ``.json``)."""
    path = Path(path)
    data = load_mapping(path, "campaign file", "campaign_file", CampaignError)
    campaign = campaign_from_mapping(data, str(path), path.parent)
    if not campaign.name:
        campaign.name = path.stem
    return campaign


def campaign_row(point: CampaignPoint, row: dict) -> dict:
    """A Monte Carlo row: the run, its figures, the plant's drawn parameters (``plant.<name>``)."""
    return {"run": point.run, **row, "noise_seed": point.noise_seed,
            **{f"plant.{k}": v for k, v in sorted(point.plant.items())}}


# ---------------------------------------------------------------------------------------------------------------
# the engine


def run_chunk(points: list[GridPoint], cycles: int) -> list[dict]:
    """A worker's task: run each point and return its comparison row (not its samples)."""
    return [point_figures(p, run_point(p, cycles)) for p in points]


def _worker_fingerprint() -> str:
    """The sources of sim/ as this process imported them (a worker's, or this one's)."""
    return SOURCES_AT_IMPORT


def _worker_warm_up() -> bool:
    warm_up()
    return True


def chunk_size(n_points: int, workers: int) -> int:
    """Points per task: about 20 tasks per worker (a smooth progress bar and a short tail), at most 16 points
    (the scheduler's cost per task, about a millisecond, spread over 16 runs)."""
    return max(1, min(16, n_points // max(1, 20 * workers)))


class Engine:
    """``dask.distributed``: a local cluster (``workers`` processes, default all cores; ``processes=False``:
    threads in this process, for tests) or the cluster of ``scheduler``. A context manager."""

    def __init__(self, scheduler: str | None = None, workers: int | None = None,
                 timeout_s: float = SCHEDULER_TIMEOUT_S, processes: bool = True):
        self.scheduler = scheduler
        self.workers = workers or os.cpu_count() or 1
        self.timeout_s = timeout_s
        self.processes = processes
        self.cluster = None
        self.client = None
        self.startup_s = 0.0

    def __enter__(self) -> Engine:
        t0 = time.perf_counter()
        try:
            self.start()
        except BaseException:
            self.close()
            raise
        self.startup_s = time.perf_counter() - t0
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def description(self) -> str:
        where = f"the cluster at {self.scheduler}" if self.scheduler else "a local dask cluster"
        return f"{where} ({self.n_workers} worker{'s' if self.n_workers != 1 else ''})"

    @property
    def n_workers(self) -> int:
        if self.client is None:
            return self.workers
        return len(self.client.nthreads()) or self.workers

    def start(self) -> None:
        from distributed import Client, LocalCluster

        if self.scheduler is None:
            warm_up()  # compile (or load) once here, so the workers load the cache instead of compiling
            self.cluster = LocalCluster(n_workers=self.workers, threads_per_worker=1, processes=self.processes,
                                        dashboard_address=None, silence_logs=logging.ERROR)
            self.client = Client(self.cluster, set_as_default=False)
        else:
            self.client = connect(self.scheduler, self.timeout_s)
        self.client.run(_worker_warm_up)

    def close(self) -> None:
        if self.client is not None:
            self.client.close()
            self.client = None
        if self.cluster is not None:
            self.cluster.close()
            self.cluster = None

    def run(self, points: list[GridPoint], cycles: int = CYCLES, progress=None) -> tuple[list[dict], float]:
        """Run every point; returns (rows in the order of ``points``, wall time in s). ``progress(done, total)``
        is called as tasks finish."""
        for p in points:
            p.scenario(cycles).validate()  # as run_batch does: refuse a bad point before anything runs
        return self.map(functools.partial(run_chunk, cycles=cycles), points, chunk_size(len(points), self.n_workers),
                        progress)

    def map(self, function, items: list, chunk: int, progress=None) -> tuple[list, float]:
        """``function`` (of a list of items, returning one row per item) over ``items`` in chunks of ``chunk``;
        (the rows in the order of ``items``, wall time in s). ``progress(done, total)`` as tasks finish."""
        from distributed import as_completed

        t0 = time.perf_counter()
        chunks = [items[i:i + chunk] for i in range(0, len(items), chunk)]
        futures = self.client.map(function, chunks, pure=False)
        sizes = {f.key: len(c) for f, c in zip(futures, chunks, strict=True)}
        done = 0
        try:
            for future in as_completed(futures, loop=self.client.loop):
                future.result()  # a task's error here, at once
                done += sizes[future.key]
                if progress is not None:
                    progress(done, len(items))
            rows = [row for future in futures for row in future.result()]
        except (CancelledError, OSError) as exc:
            raise CampaignError("scheduler", self.scheduler, "a scheduler that answers", f"lost "
                                f"{self.description} in the middle of the campaign ({type(exc).__name__}: {exc}); "
                                "nothing was written") from None
        finally:
            self.client.cancel(futures)
        return rows, time.perf_counter() - t0


def probe_scheduler(address: str, timeout_s: float = SCHEDULER_TIMEOUT_S):
    """The identity of whatever answers at ``address`` (a dict with "type": "Scheduler" for a dask scheduler),
    within ``timeout_s`` whatever happens: ``distributed.Client`` alone can wait forever on a port that accepts
    the connection and never speaks dask's protocol."""
    import asyncio
    from concurrent.futures import ThreadPoolExecutor

    from distributed.comm import connect as open_comm

    async def identity():
        comm = await open_comm(address, timeout=timeout_s)
        try:
            await comm.write({"op": "identity", "reply": True})
            return await comm.read()
        finally:
            comm.abort()

    def ask():
        return asyncio.run(asyncio.wait_for(identity(), timeout_s))

    with ThreadPoolExecutor(1) as pool:  # its own event loop, whatever the caller runs
        try:
            return pool.submit(ask).result()
        except (ValueError, TypeError) as exc:
            raise CampaignError("scheduler", address, "a scheduler address such as tcp://HOST:8786", f"{address!r}"
                                f" is not a scheduler address such as tcp://HOST:8786 ({exc})") from None
        except Exception as exc:  # refused, timed out, or not dask's protocol (even a MemoryError on its bytes)
            detail = ("nothing answered" if isinstance(exc, TimeoutError) else
                      "what it sent is not dask's protocol" if isinstance(exc, MemoryError) else
                      str(exc) or type(exc).__name__)
            raise CampaignError("scheduler", address, "a dask scheduler that answers", f"no dask scheduler "
                                f"answered at {address} within {timeout_s:g} s ({detail[:200]}); start one (`dask "
                                "scheduler`, then `dask worker ADDRESS` on each machine) or leave out --scheduler "
                                "for a local cluster") from None


def connect(address: str, timeout_s: float = SCHEDULER_TIMEOUT_S):
    """A client of the dask scheduler at ``address`` with at least one worker that runs this isorig; a clear
    ``CampaignError`` within about ``timeout_s`` otherwise."""
    from distributed import Client

    identity = probe_scheduler(address, timeout_s)
    if not (isinstance(identity, dict) and identity.get("type") == "Scheduler"):
        kind = identity.get("type") if isinstance(identity, dict) else type(identity).__name__
        raise CampaignError("scheduler", address, "a dask scheduler", f"{address} answered, but it is not a dask "
                            f"scheduler ({kind!r}); give the scheduler's address (tcp://HOST:8786 by default)")
    try:
        client = Client(address, timeout=timeout_s, set_as_default=False)
    except (OSError, TimeoutError) as exc:
        raise CampaignError("scheduler", address, "a dask scheduler that answers", f"no dask scheduler answered at "
                            f"{address} within {timeout_s:g} s ({exc}); start one (`dask scheduler`, then `dask "
                            "worker ADDRESS` on each machine) or leave out --scheduler for a local cluster") from None
    except (ValueError, TypeError) as exc:
        raise CampaignError("scheduler", address, "a scheduler address such as tcp://HOST:8786", f"{address!r} is "
                            f"not a scheduler address such as tcp://HOST:8786 ({exc})") from None
    try:
        try:
            client.wait_for_workers(1, timeout=timeout_s)
        except (TimeoutError, OSError):
            raise CampaignError("scheduler", address, "a scheduler with workers", f"the dask scheduler at {address}"
                                f" has no workers (waited {timeout_s:g} s); start some with `dask worker "
                                f"{address}`") from None
        try:
            prints = client.run(_worker_fingerprint)
        except Exception as exc:  # noqa: BLE001 - anything a worker without isorig may raise
            raise CampaignError("scheduler", address, "workers with isorig installed", f"the workers of {address} "
                                f"cannot run isorig's engine ({type(exc).__name__}: {exc}); install this isorig "
                                "on them") from None
        here = _worker_fingerprint()
        other = sorted({fp for fp in prints.values() if fp != here})
        if other:
            raise CampaignError("scheduler", address, "workers with this isorig", f"the workers of {address} run a "
                                f"different isorig (sim sources {', '.join(other)}; here {here}): their numbers "
                                "would not be this version's; install this isorig on them")
    except BaseException:
        client.close()
        raise
    return client


# ---------------------------------------------------------------------------------------------------------------
# the process pool it replaces, measured against it


def same_rows(a: list[dict], b: list[dict]) -> bool:
    """Rows equal value for value (NaN equal to NaN)."""
    def same(x, y):
        if isinstance(x, float) and isinstance(y, float) and math.isnan(x) and math.isnan(y):
            return True
        return x == y

    return len(a) == len(b) and all(r.keys() == s.keys() and all(same(r[k], s[k]) for k in r)
                                    for r, s in zip(a, b, strict=True))


def _cpu_seconds() -> float:
    """CPU time (user + system) of this process, every thread."""
    return time.process_time()


def _children_cpu_seconds() -> float:
    import resource

    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def compare_backends(points: list[GridPoint], cycles: int, engine: Engine, rounds: int = 2) -> dict:
    """The same runs in one process, then on the process pool (``run_grid``: ``sim.engine.run_batch``, figures in
    the parent) and on ``engine`` (figures in the workers) one after the other, ``rounds`` times each.

    For each path its wall time (the best round: the least disturbed by whatever else the machine runs) and its
    CPU time, all of its processes (this one with the scheduler and the nannies, the pool's or the cluster's
    workers), which other loads on the machine hardly change. A path's overhead per run is what it spends beyond
    the in-line cost of a run: CPU per run less the in-line CPU per run; wall x workers / runs less the in-line
    wall per run."""
    workers = engine.n_workers
    local_workers = engine.cluster is not None and engine.processes
    load_before = os.getloadavg()[0]
    t0, c0 = time.perf_counter(), _cpu_seconds()
    inline = [point_figures(p, run_point(p, cycles)) for p in points]
    inline_s, inline_cpu = time.perf_counter() - t0, _cpu_seconds() - c0
    walls: dict[str, list[float]] = {"process_pool": [], "distributed": []}
    cpus: dict[str, list[float]] = {"process_pool": [], "distributed": []}
    identical = True

    def engine_cpu() -> float:
        own = _cpu_seconds()
        return own + (sum(engine.client.run(_cpu_seconds).values()) if local_workers else 0.0)

    for _ in range(rounds):
        c0, k0 = _cpu_seconds(), _children_cpu_seconds()
        pool_rows, wall = run_grid(points, cycles=cycles, processes=workers)  # its workers end with it
        cpus["process_pool"].append(_cpu_seconds() - c0 + _children_cpu_seconds() - k0)
        walls["process_pool"].append(wall)
        c0 = engine_cpu()
        rows, wall = engine.run(points, cycles)
        cpus["distributed"].append(engine_cpu() - c0)
        walls["distributed"].append(wall)
        identical = identical and same_rows(inline, pool_rows) and same_rows(pool_rows, rows)
    n = len(points)

    def path(key):
        wall, cpu = min(walls[key]), min(cpus[key])
        return {"wall_s": wall, "walls_s": walls[key], "per_run_ms": 1e3 * wall / n,
                "overhead_per_run_ms": 1e3 * (wall * workers - inline_s) / n,
                "cpu_s": cpu, "cpus_s": cpus[key], "cpu_per_run_ms": 1e3 * cpu / n,
                "cpu_overhead_per_run_ms": 1e3 * (cpu - inline_cpu) / n}

    pool, dist = path("process_pool"), path("distributed")
    return {
        "runs": n, "cycles": cycles, "workers": workers, "rounds": rounds,
        "load_average_1min": [load_before, os.getloadavg()[0]],
        "inline": {"wall_s": inline_s, "per_run_ms": 1e3 * inline_s / n, "cpu_s": inline_cpu,
                   "cpu_per_run_ms": 1e3 * inline_cpu / n},
        "process_pool": pool, "distributed": dist, "distributed_startup_s": engine.startup_s,
        # what the distributed path costs per run beyond the process pool, as a share of a process-pool run
        "distributed_added_cpu_per_run": dist["cpu_per_run_ms"] / pool["cpu_per_run_ms"] - 1.0,
        "distributed_added_per_run": dist["per_run_ms"] / pool["per_run_ms"] - 1.0,
        "distributed_added_per_run_with_startup": (dist["wall_s"] + engine.startup_s) / pool["wall_s"] - 1.0,
        "identical": identical,
    }


def backends_table(b: dict) -> str:
    lines = [f"the same {b['runs']} runs of {b['cycles']} cycles on {b['workers']} worker(s) of this machine, one "
             f"after the other: in-line once, then the process pool and the distributed path alternately, "
             f"{b['rounds']} times each (the best round counts); overhead per run = what a path spends per run "
             f"beyond the in-line cost of a run (CPU: all its processes; wall: wall x workers / runs); load average "
             f"{b['load_average_1min'][0]:.2f} before, {b['load_average_1min'][1]:.2f} after", "",
             "| path | CPU s | CPU per run ms | CPU overhead per run ms | wall s (every round) | wall per run ms | "
             "wall overhead per run ms |", "|---|---|---|---|---|---|---|",
             f"| in-line, one process (the runs' own cost) | {b['inline']['cpu_s']:.2f} | "
             f"{b['inline']['cpu_per_run_ms']:.2f} | - | {b['inline']['wall_s']:.2f} | {b['inline']['per_run_ms']:.2f} "
             "| - |"]
    for key, label in (("process_pool", "process pool (sim.engine.run_batch, figures in the parent)"),
                       ("distributed", "dask.distributed (sim.campaign.Engine, figures in the workers)")):
        p = b[key]
        lines.append(f"| {label} | {p['cpu_s']:.2f} | {p['cpu_per_run_ms']:.2f} | {p['cpu_overhead_per_run_ms']:.2f} "
                     f"| {p['wall_s']:.2f} ({', '.join(f'{w:.2f}' for w in p['walls_s'])}) | {p['per_run_ms']:.2f} | "
                     f"{p['overhead_per_run_ms']:.2f} |")
    pool, dist = b["process_pool"], b["distributed"]
    lines += ["", f"per run, the distributed path costs {dist['cpu_per_run_ms'] - pool['cpu_per_run_ms']:+.2f} ms CPU "
              f"against the process pool: {100 * b['distributed_added_cpu_per_run']:+.1f} % of a process-pool run "
              f"(limit +10 %); wall {dist['per_run_ms'] - pool['per_run_ms']:+.2f} ms, "
              f"{100 * b['distributed_added_per_run']:+.1f} %; with its cluster start-up "
              f"({b['distributed_startup_s']:.2f} s, once per campaign) in the wall time: "
              f"{100 * b['distributed_added_per_run_with_startup']:+.1f} %; rows identical on the three paths: "
              f"{'yes' if b['identical'] else 'NO'}"]
    return "\n".join(lines)


# ---------------------------------------------------------------------------------------------------------------
# results: distribution table, CSV, figure


def _quantile(values: np.ndarray, q: float) -> float:
    return float(np.quantile(values, q, method="inverted_cdf"))


def error_distribution(rows: list[dict]) -> dict:
    """The distribution of RMS last2 (share of the amplitude) over ``rows``; a diverged or non-finite run
    counts as infinite."""
    v = np.array([r["rms_last2"] if (math.isfinite(r["rms_last2"]) and not r["diverged"]) else math.inf
                  for r in rows])
    return {"runs": len(rows), "meet_targets": sum(meets_targets(r) for r in rows),
            "median": _quantile(v, 0.5), "p90": _quantile(v, 0.9), "p99": _quantile(v, 0.99), "max": float(v.max()),
            "within_target": float(np.mean(v < TARGETS["rms_last2"])), "diverged": sum(r["diverged"] for r in rows),
            "limit_cycles": sum(limit_cycle(r) for r in rows)}


DISTRIBUTION_HEADER = ("group", "runs", "meet all targets", "RMS last2 % median", "p90", "p99", "max",
                       "share < 1 %", "limit cycles", "diverged")


def distribution_table(groups: dict[str, list[dict]], markdown: bool = True) -> str:
    cells = [DISTRIBUTION_HEADER]
    for name, rows in groups.items():
        d = error_distribution(rows)
        cells.append((name, str(d["runs"]), str(d["meet_targets"]), *(f"{100 * d[k]:.3f}" for k in
                      ("median", "p90", "p99", "max")), f"{100 * d['within_target']:.1f} %", str(d["limit_cycles"]),
                      str(d["diverged"])))
    if markdown:
        lines = ["| " + " | ".join(cells[0]) + " |", "|" + "---|" * len(cells[0])]
        return "\n".join(lines + ["| " + " | ".join(c) + " |" for c in cells[1:]])
    widths = [max(len(c[i]) for c in cells) for i in range(len(cells[0]))]
    return "\n".join("  ".join(c[i].rjust(widths[i]) for i in range(len(c))) for c in cells)


def parameters_table(campaign: Campaign) -> str:
    lines = ["| plant parameter | nominal (the controller's) | drawn from | allowed range | drawn again |",
             "|---|---|---|---|---|"]
    for name, dist in sorted(campaign.distributions.items()):
        lo, hi, unit = parameter_range(name)
        nominal = getattr(campaign.isolator, name) if name in ISOLATOR_PARAMETERS else \
            getattr(campaign.nominal_rig, name)
        lines.append(f"| {name} | {nominal:g} {unit} | {dist.describe()} | [{lo:g}, {hi:g}] | "
                     f"{campaign.redrawn.get(name, 0)} |")
    lines.append(f"\nruns drawn again because their draws together could not be a rig: "
                 f"{campaign.redrawn.get('inconsistent', 0)}")
    return "\n".join(lines)


def csv_text(rows: list[dict]) -> str:
    """Every row with its ``meets_targets`` and ``limit_cycle`` flags; floats at full precision."""
    import io

    out = io.StringIO()
    columns = list(rows[0]) + ["meets_targets", "limit_cycle"] if rows else []
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(columns)
    for r in rows:
        full = {**r, "meets_targets": meets_targets(r), "limit_cycle": limit_cycle(r)}
        writer.writerow([repr(v) if isinstance(v, float) else v for v in (full.get(c, "") for c in columns)])
    return out.getvalue()


def error_figure(groups: dict[str, list[dict]], title: str):
    """The ECDF of RMS last2 / amplitude per group (log scale), the 1 % target marked."""
    from matplotlib.figure import Figure

    many = len(groups) > 8
    fig = Figure(figsize=(8.0, 5.0 + (0.16 * len(groups) if many else 0.0)), layout="constrained")
    ax = fig.subplots()
    for name, rows in groups.items():
        v = np.sort([100 * r["rms_last2"] for r in rows if math.isfinite(r["rms_last2"]) and not r["diverged"]])
        n = len(rows)
        d = error_distribution(rows)
        label = f"{name}: n = {n}, median {100 * d['median']:.3g} %, p90 {100 * d['p90']:.3g} %"
        if d["diverged"] or len(v) < n:
            label += f", {n - len(v)} diverged"
        if len(v):
            ax.step(np.concatenate([[v[0]], v]), np.arange(len(v) + 1) / n, where="post", label=label)
    target = 100 * TARGETS["rms_last2"]
    ax.axvline(target, color="k", linestyle="--", linewidth=1.0, label=f"target {target:g} %")
    ax.set_xscale("log")
    ax.set_ylim(0.0, 1.02)
    ax.set_xlabel("RMS of y - r over the last two cycles / amplitude (%)")
    ax.set_ylabel("share of runs at or below")
    ax.set_title(title, fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    if many:
        fig.legend(loc="outside lower center", fontsize=6, ncols=2)
    else:
        ax.legend(fontsize=8, loc="lower right")
    return fig


class Outputs:
    """The CSV and the figure, checked before anything runs and written at the end through temporary files
    renamed into place: nothing is half-written."""

    def __init__(self, csv_path: str | None = None, figure_path: str | None = None):
        self.csv_path = Path(csv_path) if csv_path else None
        self.figure_path = Path(figure_path) if figure_path else None
        for label, p in (("--csv", self.csv_path), ("--figure", self.figure_path)):
            if p is None:
                continue
            if p.is_dir():
                raise CampaignError(label, str(p), "a file name", f"{label} {p} is a directory, not a file name")
            if not p.parent.is_dir():
                raise CampaignError(label, str(p), "a file in an existing directory", f"{label} {p}: the directory "
                                    f"{p.parent} does not exist")
            if not os.access(p.parent, os.W_OK):
                raise CampaignError(label, str(p), "a writable directory", f"{label} {p}: cannot write in "
                                    f"{p.parent}")
        if self.figure_path is not None and self.figure_path.suffix.lower() not in FIGURE_FORMATS:
            raise CampaignError("--figure", str(self.figure_path), ", ".join(FIGURE_FORMATS), f"--figure "
                                f"{self.figure_path}: the name must end in {', '.join(FIGURE_FORMATS)}")
        if self.csv_path is not None and self.figure_path is not None and \
                self.csv_path.resolve() == self.figure_path.resolve():
            raise CampaignError("--figure", str(self.figure_path), "another file than --csv", "--csv and --figure "
                                "name the same file")

    def write(self, rows: list[dict], groups: dict[str, list[dict]], title: str, text: str | None = None,
              figure=None) -> list[Path]:
        """Write both (temporary names first, renamed when both are complete); returns the paths written.
        ``text`` and ``figure`` (a matplotlib figure) replace the comparison's CSV and error figure."""
        import tempfile

        temps: list[tuple[Path, Path]] = []
        try:
            if self.csv_path is not None:
                fd, tmp = tempfile.mkstemp(dir=self.csv_path.parent, prefix=f".{self.csv_path.name}.", suffix=".tmp")
                temps.append((Path(tmp), self.csv_path))
                with os.fdopen(fd, "w", newline="") as f:
                    f.write(csv_text(rows) if text is None else text)
            if self.figure_path is not None:
                fd, tmp = tempfile.mkstemp(dir=self.figure_path.parent, prefix=f".{self.figure_path.name}.",
                                           suffix=".tmp")
                temps.append((Path(tmp), self.figure_path))
                with os.fdopen(fd, "wb") as f:
                    (error_figure(groups, title) if figure is None else figure).savefig(
                        f, format=self.figure_path.suffix.lower()[1:], dpi=120)
            umask = os.umask(0)
            os.umask(umask)
            for tmp, final in temps:
                os.chmod(tmp, 0o666 & ~umask)  # mkstemp's 0600 would outlive the rename
                os.replace(tmp, final)
        except BaseException:
            for tmp, _final in temps:
                tmp.unlink(missing_ok=True)
            raise
        return [final for _tmp, final in temps]
