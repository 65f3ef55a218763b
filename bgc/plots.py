"""Plots people would rather look at than numbers: runs, residuals, estimates."""

from __future__ import annotations

import io


def _figure(rows: int, width: float = 9.0, height_per_row: float = 1.7):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(rows, 1, figsize=(width, max(2.5, height_per_row * rows)), sharex=True, squeeze=False)
    return plt, fig, axes[:, 0]


def _save(plt, fig, fmt: str) -> bytes:
    buf = io.BytesIO()
    fig.tight_layout()
    fig.savefig(buf, format=fmt, dpi=100, metadata={"Software": None} if fmt == "png" else {"Date": None})
    plt.close(fig)
    return buf.getvalue()


def simulation_figure(r, fmt: str = "png") -> bytes:
    """Measurements (noisy and clean) and, last, the faulty parameter, against time."""
    n = len(r.output_names) + (1 if r.fault else 0)
    plt, fig, axes = _figure(n)
    for j, name in enumerate(r.output_names):
        ax = axes[j]
        ax.plot(r.time, r.measurements[:, j], ".", ms=2.5, color="#c03030", label="measured")
        ax.plot(r.time, r.clean_measurements[:, j], "-", lw=1.0, color="#202020", label="noise-free")
        ax.set_ylabel(name)
        if r.fault:
            ax.axvline(r.fault.time, color="#808080", ls=":", lw=1)
    if r.fault:
        ax = axes[-1]
        ax.plot(r.time, r.parameter, color="#2060c0")
        ax.set_ylabel(r.fault.parameter)
    axes[0].legend(loc="best", fontsize=7)
    axes[0].set_title(f"{r.model}: simulated run ({r.fault.describe() if r.fault else 'no fault'})")
    axes[-1].set_xlabel("time")
    return _save(plt, fig, fmt)
