"""`isorig serve` and `isorig bench-stream` refuse bad arguments with one line and exit code 2."""

from __future__ import annotations

from isorig.cli import main


def test_serve_bad_port_and_database(tmp_path, capsys):
    assert main(["serve", "--port", "0", "--data-dir", str(tmp_path)]) == 2
    assert "--port 0" in capsys.readouterr().err
    assert main(["serve", "--database-url", "nonsense://", "--data-dir", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "cannot open the database" in err and "Traceback" not in err
    assert main(["serve", "--database-url", "postgresql+psycopg://u:secretpw@127.0.0.1:1/x",
                 "--data-dir", str(tmp_path)]) == 2
    assert "secretpw" not in capsys.readouterr().err


def test_bench_stream_bad_arguments(capsys):
    assert main(["bench-stream", "--duration-s", "1"]) == 2
    assert "--duration-s" in capsys.readouterr().err
