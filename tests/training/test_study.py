"""The study's report from given results (no training): tables, ordering, findings."""
import numpy as np

from training import metrics as M
from training.study import PAPER_T1, TEXTURES, findings, write_report


def _m(mae):
    rng = np.random.default_rng(int(mae * 1000))
    true = rng.uniform(-30, 30, (50, 3))
    return M.compute(true + rng.choice([-1, 1], true.shape) * mae, true)


def test_report_tables_and_ordering(tmp_path):
    maes = dict(zip(TEXTURES, [1.2, 1.0, 0.8, 0.9, 0.5, 0.4]))
    results = {t: {"val": _m(v), "test": _m(v + 0.1), "test_offgrid": _m(v + 0.2)} for t, v in maes.items()}
    timings = {t: {"train_s": 10, "device": "CPU"} for t in TEXTURES}
    prof = {"arch": "mobilenet_v2", "size": 64, "epochs": 1, "batch_size": 8, "dataset": ["--train", "8"]}
    write_report(tmp_path, "quick", prof, list(TEXTURES), results, timings, 60)
    md = (tmp_path / "report.md").read_text()
    assert "| Texture | Err_X | Err_Y | Err_Z | Std_X | Std_Y | Std_Z | MAE | RMSE |" in md
    assert "| Texture_3_color | 0.400 | 0.400 | 0.400 | 0.000 | 0.000 | 0.000 | 0.400 | 0.400 |" in md
    assert "validation MAE: Texture_3_color (0.400) < Texture_3_bw (0.500) < Texture_2_bw (0.800)" in md
    assert (tmp_path / "study_mae.png").exists() and (tmp_path / "study.json").exists()
    f = "\n".join(findings(list(TEXTURES), results))
    assert "validation, bw: MAE 1.200 -> 0.800 -> 0.500 from Texture 1 to 3: falls monotonically" in f
    assert "validation, Texture 2: colour 0.900 vs bw 0.800: colour does not help" in f


def test_paper_rows_consistent():
    # the paper's MAE is the mean of its Err columns (to its rounding)
    for t, (err, std, mae, rmse) in PAPER_T1.items():
        assert abs(np.mean(err) - mae) < 0.002, t
