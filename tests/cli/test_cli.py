"""The `solidkit` command: groups listed, usage errors are one line (no traceback)."""

import subprocess
import sys

import pytest


def run(*args):
    return subprocess.run([sys.executable, "-m", "solidkit.cli", *args], capture_output=True, text=True, timeout=300)


def test_help_lists_groups():
    res = run("--help")
    assert res.returncode == 0
    for group in ("envmap", "capture", "ingest", "demo"):
        assert group in res.stdout


@pytest.mark.parametrize("args", [("envmap", "sun", "x.exr", "--bogus"), ("envmap", "rotate")])
def test_usage_errors_are_one_line(args):
    res = run(*args)
    assert res.returncode == 2
    assert "Traceback" not in res.stderr + res.stdout


def test_demo_json_is_its_summary(cli, monkeypatch, tmp_path):
    """``solidkit demo --json``: the summary alone on stdout (what OUT/summary.json holds); a failed step exits 1."""
    import json

    import solidkit.demo

    summary = {
        "card": "card",
        "out": str(tmp_path),
        "seconds": 1.5,
        "report": str(tmp_path / "report.html"),
        "steps": [{"name": "ingest", "status": "ok", "seconds": 0.5, "note": "3 scenes"}],
    }
    monkeypatch.setattr(solidkit.demo, "run_demo", lambda out, cfg, log: summary)
    code, out, _ = cli("demo", "-o", tmp_path, "--json")
    assert code == 0 and json.loads(out) == summary
    summary["steps"][0]["status"] = "failed"
    code, out, _ = cli("demo", "-o", tmp_path, "--json")
    assert code == 1 and json.loads(out)["steps"][0]["status"] == "failed"
    code, out, err = cli("demo", "-o", tmp_path)
    assert code == 1 and out.startswith("report: ") and "ingest" in err


def test_the_command_list_is_the_full_apps_and_imports_no_command():
    """``solidkit --help`` lists every command from the table alone (no command module imported), and the
    list is exactly what the full app prints."""
    from typer.testing import CliRunner

    from solidkit.cli import build_app

    def help_of(app):
        res = CliRunner().invoke(app, ["--help"], prog_name="solidkit", terminal_width=100)
        assert res.exit_code == 0, res.output
        return res.output

    assert help_of(build_app(listing=True)) == help_of(build_app())
    probe = (
        "import sys; sys.argv = ['solidkit', '--help']\nfrom solidkit.cli import main\ntry:\n    main()\n"
        "except SystemExit:\n    pass\nprint(sorted(m for m in sys.modules if m.startswith('solidkit.cli.')))"
    )
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True).stdout
    assert out.strip().splitlines()[-1] == "[]"
