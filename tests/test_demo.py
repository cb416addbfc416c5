"""`jaxpose demo` (the README's first command) runs and reports every section."""

from jaxpose.cli import main


def test_demo_runs_and_writes_its_figures(tmp_path, capsys):
    assert main(["demo", "--cases", "4", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "1. DOP and feature selection" in out and "2. Monocular pose initialisation" in out
    assert (tmp_path / "selection" / "fig6_ratio_histograms.png").stat().st_size > 10_000
    assert (tmp_path / "monocular" / "monocular_overlay.png").stat().st_size > 10_000
    assert (tmp_path / "report.txt").read_text().startswith("jaxpose demo")
