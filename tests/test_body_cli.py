"""``pedx-graph info``."""
from pedx_graph.body import model as model_module
from pedx_graph.cli import main


def test_info_prints_counts_heights_and_provenance(synthetic_smpl_file, capsys):
    assert main(["info", "--model", str(synthetic_smpl_file)]) == 0
    out = capsys.readouterr().out
    assert "vertices:   300" in out and "joints:     24" in out and "faces:      600" in out
    assert "mean shape" in out and "beta1 = +2" in out
    assert "synthetic_model_arrays" in out            # provenance builder
    heights = [float(line.split()[-2]) for line in out.splitlines() if line.strip().startswith(("mean", "beta1"))]
    mean, minus, plus = heights
    assert minus < mean < plus                        # component 0 of the synthetic model scales height


def test_info_without_default_model_is_graceful(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(model_module, "default_model_path", lambda: tmp_path / "missing.npz")
    assert main(["info"]) == 1
    err = capsys.readouterr().err
    assert "not installed" in err and "pass an SMPL-format" in err


def test_info_reports_invalid_file(tmp_path, capsys):
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"nonsense")
    assert main(["info", "--model", str(bad)]) == 1
    assert "bad.npz" in capsys.readouterr().err
