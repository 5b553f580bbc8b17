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
