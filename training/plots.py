"""Figures like the paper's (matplotlib, Agg): Fig. 3 error distributions per axis,
Fig. 4 true-vs-predicted scatter + error line + error histogram per axis,
Fig. 6 box plot of errors; and the study's per-texture comparisons."""
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from sim.pose import wrap_deg  # noqa: E402

AXES = ("X", "Y", "Z")
COLOURS = ("tab:red", "tab:green", "tab:blue")


def _save(fig, path):
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def error_distribution(pred, true, path, title=""):
    """Fig. 3: histogram of |error| per axis with mean (Err) and Std marked."""
    e = np.abs(wrap_deg(pred - true))
    fig, axs = plt.subplots(1, 3, figsize=(12, 3.4), sharey=True)
    hi = max(float(np.percentile(e, 99.5)), 1e-3)
    for a, ax in enumerate(axs):
        ax.hist(e[:, a], bins=40, range=(0, hi), color=COLOURS[a], alpha=0.75)
        m, s = e[:, a].mean(), e[:, a].std()
        ax.axvline(m, color="k", lw=1.5, label=f"Err {m:.3f}°")
        ax.axvspan(max(0, m - s), m + s, color="k", alpha=0.08, label=f"Std {s:.3f}°")
        ax.set_xlabel(f"|error| {AXES[a]} (°)")
        ax.legend(fontsize=8)
    axs[0].set_ylabel("frames")
    fig.suptitle(title or "error distribution per axis")
    _save(fig, path)


def test_panels(pred, true, path, title=""):
    """Fig. 4: per axis, true vs predicted scatter, signed error per sample, error histogram."""
    d = wrap_deg(pred - true)
    fig, axs = plt.subplots(3, 3, figsize=(12, 10))
    for a in range(3):
        ax = axs[0, a]
        ax.scatter(true[:, a], pred[:, a], s=6, color=COLOURS[a])
        lo, hi = float(min(true[:, a].min(), pred[:, a].min())), float(max(true[:, a].max(), pred[:, a].max()))
        ax.plot([lo, hi], [lo, hi], "k--", lw=0.8)
        ax.set_xlabel(f"true {AXES[a]} (°)")
        ax.set_ylabel(f"predicted {AXES[a]} (°)")
        ax = axs[1, a]
        ax.plot(np.arange(len(d)), d[:, a], color=COLOURS[a], lw=0.8)
        ax.axhline(0, color="k", lw=0.6)
        ax.set_xlabel("sample")
        ax.set_ylabel(f"error {AXES[a]} (°)")
        ax = axs[2, a]
        ax.hist(d[:, a], bins=30, color=COLOURS[a], alpha=0.75)
        ax.set_xlabel(f"error {AXES[a]} (°)")
        ax.set_ylabel("frames")
    fig.suptitle(title or "true vs predicted, error line, error histogram")
    _save(fig, path)


def box(pred, true, path, title=""):
    """Fig. 6: box plot of |error| per axis."""
    e = np.abs(wrap_deg(pred - true))
    fig, ax = plt.subplots(figsize=(5, 4))
    ax.boxplot([e[:, a] for a in range(3)], tick_labels=list(AXES), showfliers=True)
    ax.set_ylabel("|error| (°)")
    ax.set_title(title or "absolute error per axis")
    _save(fig, path)


def split_figures(pred, true, out_dir, split, label=""):
    """All per-split figures; returns the file names written."""
    t = f"{label} {split}".strip()
    names = [f"{split}_fig3_error_distribution.png", f"{split}_fig4_test_panels.png", f"{split}_fig6_box.png"]
    error_distribution(pred, true, out_dir / names[0], f"{t}: error distribution")
    test_panels(pred, true, out_dir / names[1], f"{t}: true vs predicted / error / histogram")
    box(pred, true, out_dir / names[2], f"{t}: absolute error")
    return names


def study_bars(rows, path, keys=(("val", "mae"), ("test", "mae"), ("test_offgrid", "mae"))):
    """Grouped bars of MAE per texture and split. rows: [(texture, {split: metrics})]."""
    fig, ax = plt.subplots(figsize=(10, 4))
    n = len(keys)
    x = np.arange(len(rows))
    for k, (split, key) in enumerate(keys):
        vals = [r[1].get(split, {}).get(key, np.nan) for r in rows]
        ax.bar(x + (k - (n - 1) / 2) * 0.8 / n, vals, 0.8 / n, label=f"{split} {key.upper()}")
    ax.set_xticks(x, [r[0] for r in rows], rotation=20)
    ax.set_ylabel("degrees")
    ax.legend()
    _save(fig, path)


def study_box(rows, path, split="val"):
    """Box plot of mean-over-axes |error| per texture. rows: [(texture, pred, true)]."""
    fig, ax = plt.subplots(figsize=(10, 4))
    data = [np.abs(wrap_deg(p - t)).mean(1) for _, p, t in rows]
    ax.boxplot(data, tick_labels=[r[0] for r in rows], showfliers=False)
    ax.set_ylabel(f"{split}: mean |error| over axes (°)")
    plt.setp(ax.get_xticklabels(), rotation=20)
    _save(fig, path)
