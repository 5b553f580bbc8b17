import os
import shutil

from sim import _numba_cache


def test_cache_folder_follows_every_source_file(tmp_path):
    root = tmp_path / "pkg"
    shutil.copytree(_numba_cache.PACKAGE_DIR, root, ignore=shutil.ignore_patterns("__pycache__"))
    before = _numba_cache.source_fingerprint(root)
    assert before == _numba_cache.source_fingerprint(root)  # stable
    controller = root / "controllers" / "pid.py"
    controller.write_text(controller.read_text() + "\n# changed\n")
    assert _numba_cache.source_fingerprint(root) != before  # a controller edit moves the whole cache


def test_numba_uses_the_fingerprinted_folder():
    import numba

    expected = os.environ.get("NUMBA_CACHE_DIR")
    assert expected
    assert numba.config.CACHE_DIR == expected


def test_every_kernel_of_the_engine_loop_divides_as_numpy_does():
    """The engine's kernels are compiled with error_model="numpy": no zero-divisor check before each division
    (a sixth of the loop's time), and a division by zero gives inf or NaN, which the loop's NaN guard
    (sim.loop.saturate) and the plant's finiteness check handle, in every kernel alike."""
    from numba.core.registry import CPUDispatcher

    from sim import controllers, isolator, loop, models, plant, profiles, rig, sensors
    from sim.controllers import excitation, mrac, pid, servo

    kernels = [(m.__name__, name, f) for m in (controllers, excitation, mrac, pid, servo, isolator, loop, models,
                                                plant, profiles, rig, sensors)
               for name, f in vars(m).items() if isinstance(f, CPUDispatcher) and f.__module__ == m.__name__]
    assert len(kernels) > 30
    assert [(m, name) for m, name, f in kernels if f.targetoptions.get("error_model") != "numpy"] == []
