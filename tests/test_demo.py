"""`jaxpose demo` (the README's first command) runs and reports every section."""

from jaxpose.cli import main


def test_demo_runs_and_writes_its_figures(tmp_path, capsys):
    assert main(["demo", "--cases", "4", "--stereo-frames", "6", "--out", str(tmp_path)]) == 0
    out, err = capsys.readouterr()
    # Progress on stderr for each section (the monocular call is silent for minutes otherwise).
    for label in ("demo 1/3: selection study", "demo 2/3: monocular", "demo 3/3: stereo tracking"):
        assert label in err
    assert "1. DOP and feature selection" in out and "2. Monocular pose initialisation" in out
    assert "3. Stereo point-line tracking" in out and "lost frames: 0" in out
    assert (tmp_path / "stereo" / "fig5_attitude.png").stat().st_size > 10_000
    assert len((tmp_path / "stereo" / "trajectory.csv").read_text().splitlines()) == 7
    assert (tmp_path / "selection" / "fig6_ratio_histograms.png").stat().st_size > 10_000
    assert (tmp_path / "monocular" / "monocular_overlay.png").stat().st_size > 10_000
    assert (tmp_path / "report.txt").read_text().startswith("jaxpose demo")


def test_demo_rejects_a_bad_frame_count_before_running(tmp_path, capsys):
    assert main(["demo", "--stereo-frames", "1", "--out", str(tmp_path)]) == 2
    assert "--stereo-frames" in capsys.readouterr().err
    assert not (tmp_path / "selection").exists()  # nothing ran
