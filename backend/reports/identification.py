"""The Bouc-Wen identification of a report: the fit of sim.identify_bouc_wen on the first minute of the record.

``identification_task`` decides what to fit (small and picklable, so another process can run it with
``run_identification`` meanwhile, as ``isorig report`` does); ``identified_bouc_wen`` does both here.
"""

from __future__ import annotations

import math

import numpy as np

from .data import clean_json, isolator_of, num

BOUC_WEN_FIELDS = ("rho_bw_per_m", "sigma_bw", "n", "kd_n_per_m", "kw_n")
IDENTIFY_MAX_SAMPLES = 60_000  # the Bouc-Wen fit uses the first 60 000 samples (60 s at 1 kHz) ...
IDENTIFY_FIT_POINTS = 6_000  # ... thinned to at most 6 000 points (>= 100 Hz), to keep the report fast


def identified_bouc_wen(bundle, max_samples: int = IDENTIFY_MAX_SAMPLES) -> dict:
    """Bouc-Wen parameters identified from the test's record beside the nominal ones.

    Uses a stored result (``record["identification"]`` with ``identified``) when there is one; else calls
    ``fit_bouc_wen`` of sim.identify_bouc_wen on the first ``max_samples`` samples
    (the fit assumes the record starts at rest, so it must start at the beginning), thinned to at most
    IDENTIFY_FIT_POINTS points, starting from the nominal rho_BW, sigma_BW, n. Returns {"available": False,
    "note": why} when the fit fails or the record has too little motion.
    """
    answer, task = identification_task(bundle, max_samples)
    return answer if task is None else run_identification(answer, task)


def identification_task(bundle, max_samples: int = IDENTIFY_MAX_SAMPLES) -> tuple[dict, tuple | None]:
    """What identified_bouc_wen decides before fitting: its answer so far and the fit to run (None: none).

    The task is small and pickles (at most IDENTIFY_FIT_POINTS samples and the start), so another process can
    run it with run_identification while this one goes on (``isorig report`` does); the fit is imported there.
    """
    nominal = isolator_of(bundle.record)
    out = {"available": False, "nominal": nominal.to_dict() if nominal else None}
    stored = bundle.record.get("identification")
    if isinstance(stored, dict) and stored.get("identified"):
        return {**out, **stored, "available": True, "source": "stored with the test"}, None
    s = bundle.samples
    stride = max(1, math.ceil(min(max_samples, len(s)) / IDENTIFY_FIT_POINTS))
    t, d, f = (np.ascontiguousarray(s[c][:max_samples:stride]) for c in ("time_s", "displacement_m", "force_n"))
    bad = ~(np.isfinite(t) & np.isfinite(d) & np.isfinite(f))
    if bad.any():
        t, d, f = t[:int(np.argmax(bad))], d[:int(np.argmax(bad))], f[:int(np.argmax(bad))]
    if t.size < 100 or np.ptp(d) <= 0:
        out["note"] = "too few samples with motion to identify"
        return out, None
    start = None if nominal is None else {"rho_bw_per_m": nominal.rho_bw_per_m, "sigma_bw": nominal.sigma_bw,
                                          "n": nominal.n}
    return out, (t, d, f, start)


def run_identification(answer: dict, task: tuple) -> dict:
    """Run the fit of identification_task and complete its answer (a failure becomes a note, never raises)."""
    import time

    from sim.identify_bouc_wen import fit_bouc_wen

    t, d, f, start = task
    out = dict(answer)
    t0 = time.perf_counter()
    try:
        result = fit_bouc_wen(t, d, f, name="identified", start=start)
    except Exception as exc:  # an identification failure must not cost the report
        out["note"] = f"identification failed: {type(exc).__name__}: {exc}"[:300]
        return out
    params = {k: float(getattr(result.isolator, k)) for k in BOUC_WEN_FIELDS
              if num(float(getattr(result.isolator, k))) is not None}
    if not params:
        out["note"] = "the identification returned no Bouc-Wen parameters"
        return out
    quality = {k: getattr(result, k) for k in ("nrms_error", "rms_error_n", "relative_std", "flat_directions")}
    out.update({"available": True, "identified": params, "fit": clean_json(quality), "samples_used": int(t.size),
                "record_span_s": float(t[-1] - t[0]), "time_s": time.perf_counter() - t0,
                "source": "fit_bouc_wen on the first " + f"{t[-1] - t[0]:.3g} s of the record"})
    return out
