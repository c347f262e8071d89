#!/usr/bin/python3
"""Plots of the benchmark run (make bench): reads the CSV files the benchmark suite wrote into
DIR and writes PNGs next to them. Debian's /usr/bin/python3 with python3-matplotlib and
python3-numpy.

Usage: scripts/plots.py DIR
"""
import csv
import os
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


def rows(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def short(method):
    return method.split(" (")[0] if len(method) > 38 else method


def success_vs(rows_, key, xlabel, out, logx=False):
    methods = []
    for r in rows_:
        if r["method"] not in methods:
            methods.append(r["method"])
    fig, ax = plt.subplots(figsize=(8, 4.5))
    for m in methods:
        xs = sorted({float(r[key]) for r in rows_ if r["method"] == m})
        if len(xs) < 2:
            continue
        ys = []
        for x in xs:
            sel = [int(r["success"]) for r in rows_ if r["method"] == m and float(r[key]) == x]
            ys.append(100.0 * sum(sel) / len(sel))
        ax.plot(xs, ys, marker="o", label=short(m))
    if logx:
        ax.set_xscale("log")
    ax.set_xlabel(xlabel)
    ax.set_ylabel("success rate [%]")
    ax.set_ylim(-5, 105)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)


def error_cdfs(rows_, out):
    methods = []
    for r in rows_:
        if r["method"] not in methods:
            methods.append(r["method"])
    fig, axes = plt.subplots(1, 3, figsize=(13, 4))
    for key, ax, label, scale in (("rotation_deg", axes[0], "rotation error [deg]", 1.0),
                                  ("translation", axes[1], "translation error [m]", 1.0),
                                  ("scale_rel", axes[2], "scale error [%]", 100.0)):
        for m in methods:
            v = np.sort([float(r[key]) * scale for r in rows_ if r["method"] == m])
            if len(v) == 0:
                continue
            ax.step(v, np.arange(1, len(v) + 1) / len(v), where="post", label=short(m))
        ax.set_xscale("log")
        ax.set_xlabel(label)
        ax.set_ylabel("fraction of runs")
        ax.set_ylim(0, 1.02)
        ax.grid(True, alpha=0.3)
    axes[0].legend(fontsize=6, loc="lower right")
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)


def time_vs_points(timing, peers, out):
    fig, ax = plt.subplots(figsize=(8, 4.5))
    n = [int(r["points"]) for r in timing]
    bottom = np.zeros(len(n))
    for stage in ("features", "relative_pose", "scale", "filters", "icp", "covariance", "other"):
        v = np.array([float(r.get(stage) or 0.0) for r in timing])
        ax.bar(range(len(n)), v, bottom=bottom, label="pcr_pro " + stage)
        bottom += v
    ax.set_xticks(range(len(n)))
    ax.set_xticklabels([str(x) for x in n])
    ax.set_xlabel("points per cloud")
    ax.set_ylabel("wall time [ms]")
    ax.axhline(400, color="k", ls="--", lw=1, label="400 ms floor")
    if peers:
        methods = []
        for r in peers:
            if r["method"] not in methods:
                methods.append(r["method"])
        for m in methods:
            pts = [(int(r["points"]), float(r["ms"])) for r in peers if r["method"] == m]
            xs = [n.index(p) for p, _ in pts if p in n]
            ys = [t for p, t in pts if p in n]
            if xs:
                ax.plot(xs, ys, marker="s", ls=":", label=short(m) + " (from identity)")
        ax.set_yscale("log")
    ax.legend(fontsize=7, loc="upper left")
    ax.grid(True, alpha=0.3, axis="y")
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)


def nees_hist(nees, out):
    sizes = sorted({int(r["points"]) for r in nees})
    fig, axes = plt.subplots(1, len(sizes), figsize=(4.5 * len(sizes), 3.8), squeeze=False)
    for ax, n in zip(axes[0], sizes):
        for model in ("closed_form", "calibrated", "blocks"):
            v = [float(r["nees"]) for r in nees if int(r["points"]) == n and r["model"] == model]
            if v:
                ax.hist(np.clip(v, 0, 60), bins=np.linspace(0, 60, 31), alpha=0.5, density=True,
                        label="%s (ANEES %.2f)" % (model, np.mean(v) / 6.0))
        x = np.linspace(0.01, 60, 300)
        # chi-square density with 6 degrees of freedom: x^2 e^{-x/2} / 16
        ax.plot(x, x * x * np.exp(-x / 2.0) / 16.0, "k-", lw=1, label="χ²(6)")
        ax.set_title("N = %d" % n)
        ax.set_xlabel("NEES (6-DoF)")
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)


def case_nees(path, out):
    """NEES of the reported estimates of the real or simulated cases (truth's accuracy added)."""
    cases = [r for r in rows(path) if r["method"] == "pcr_pro reported" and r["status"] == "OK"]
    if not cases:
        return
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.6))
    for ax, key, dof, bound in ((axes[0], "nees6", 6, 12.592), (axes[1], "nees_scale", 1, 3.841)):
        v = np.array([float(r[key]) for r in cases])
        ax.hist(np.clip(v, 0, 5 * bound), bins=np.linspace(0, 5 * bound, 31), alpha=0.6,
                label="reported (ANEES %.2f)" % (np.mean(v) / dof))
        ax.axvline(bound, color="k", lw=1, ls="--", label="χ²(%d) 95 %%" % dof)
        ax.set_xlabel("NEES (%s)" % ("6-DoF" if dof == 6 else "scale"))
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)


def main():
    d = sys.argv[1]
    for name in ("real_cases", "simulated"):
        if os.path.exists(os.path.join(d, name + ".csv")):
            case_nees(os.path.join(d, name + ".csv"), os.path.join(d, name + "_nees.png"))
    if not os.path.exists(os.path.join(d, "sweep.csv")):
        return
    sweep = rows(os.path.join(d, "sweep.csv"))
    success_vs(sweep, "ratio", "scale ratio of S_target_source", os.path.join(d, "success_vs_scale.png"), logx=True)
    success_vs([r for r in sweep if r["variant"] != "clouds"], "roll_deg", "keyframe roll [deg]",
               os.path.join(d, "success_vs_roll.png"))
    success_vs(sweep, "sparsity", "fraction of map points kept", os.path.join(d, "success_vs_sparsity.png"),
               logx=True)
    error_cdfs(sweep, os.path.join(d, "error_cdf.png"))
    peers_path = os.path.join(d, "timing_peers.csv")
    if os.path.exists(os.path.join(d, "timing.csv")):
        time_vs_points(rows(os.path.join(d, "timing.csv")), rows(peers_path) if os.path.exists(peers_path) else [],
                       os.path.join(d, "time_vs_points.png"))
    if os.path.exists(os.path.join(d, "nees.csv")):
        nees_hist(rows(os.path.join(d, "nees.csv")), os.path.join(d, "nees_hist.png"))


if __name__ == "__main__":
    main()
