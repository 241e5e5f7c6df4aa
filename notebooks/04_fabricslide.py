# ---
# jupyter:
#   frictionfit:
#     needs_shared: true
#   jupytext:
#     formats: ipynb,py:percent
#     notebook_metadata_filter: frictionfit
#     text_representation:
#       extension: .py
#       format_name: percent
#       format_version: '1.3'
#       jupytext_version: 1.19.6
#   kernelspec:
#     display_name: Python 3
#     language: python
#     name: python3
# ---

# %% [markdown]
# # 04 — FabricSlide: real fabrics, a real finger
#
# **Question:** on real recordings (a 16-taxel capacitive finger sliding along seven
# fabrics, Wang et al. 2022), what does the contact model see in a slide, where do the
# fabrics sit in the physical feature space, does the published spectral pipeline
# reproduce, and — the warning — how much of any accuracy comes from the grasp rather
# than the texture?
#
# This notebook needs the team's copy of the dataset (`../shared/datasets/fabricslide`,
# repetitions 0 and 1; read its README first). It is skipped where that is absent.

# %%
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
from sklearn.model_selection import train_test_split
from sklearn.neighbors import KNeighborsClassifier
from sklearn.pipeline import Pipeline

from frictionfit.classify import evaluate
from frictionfit.datasets import shared_dataset
from frictionfit.datasets.fabricslide import TAXELS, load
from frictionfit.features.sliding import SlidingPhysicalFeatures, slide_drive
from frictionfit.features.spectral import SpectralPCAFeatures
from frictionfit.fit import fit_trials

recs = load(shared_dataset("fabricslide"))
meta = pd.DataFrame([r.metadata for r in recs])
print(len(recs), "slides;", meta.groupby("fabric").size().to_dict())

# %% [markdown]
# ## One slide: raw taxels, and the contact model fitted over them
# Same condition (grip set-point 150 counts, 20 mm/s downward, repetition 0) for three
# fabrics. Top: the 16 taxels, each minus its own mean (counts). Bottom: the observable the
# contact model is fitted to — the first principal component of the centred taxels,
# scaled by its 5-95 % range — and the fitted `relaxation` member driven by the known
# travel (quarter-sine ramp, then constant speed). This is how
# `SlidingPhysicalFeatures` builds its breakaway features (there, block-averaged to 128
# points, with its own data-driven start: these fits use `fit_trials`' default start, so
# they can differ); the stick-slip period it reports from the steady part's spectrum is
# marked by the ticks.

# %%
def pc1(x: np.ndarray) -> np.ndarray:
    """First principal component of the centred columns (loadings sum > 0), / its 5-95% range."""
    xc = x - x.mean(axis=0)
    u, s, vt = np.linalg.svd(xc, full_matrices=False)
    pc = u[:, 0] * s[0] * np.sign(vt[0].sum() or 1.0)
    return pc / np.subtract(*np.percentile(pc, [95, 5]))


def block_mean(y: np.ndarray, t: np.ndarray, n: int = 128) -> tuple[np.ndarray, np.ndarray]:
    """``n`` uniform times over the slide and ``y`` smoothed by a moving mean one step wide."""
    width = max(1, round(y.size / n))
    smooth = np.convolve(np.pad(y, (width // 2, width - 1 - width // 2), mode="edge"),
                         np.full(width, 1.0 / width), mode="valid")
    grid = np.linspace(0.0, t[-1], n)
    return grid, np.interp(grid, t, smooth)


SHOWN = ("Canvas", "Denim", "Linen")
slides = [next(r for r in recs if r.metadata["fabric"] == f and r.metadata["pressure"] == 150
               and r.metadata["speed"] == -20 and r.metadata["repetition"] == 0) for f in SHOWN]
grids = [block_mean(pc1(np.column_stack([r.channel(c) for c in TAXELS])), r.t) for r in slides]
t_fit = grids[0][0]  # the three slides last equally long (same speed)
y_fit = np.vstack([g[1] for g in grids])
drive = np.vstack([slide_drive(t_fit, r.metadata["speed"], r.metadata["ramp_s"]) for r in slides])
fit = fit_trials(y_fit, t_fit, drive, model="relaxation", drive="given", max_steps=200)
cycles = SlidingPhysicalFeatures(cache=False).fit(slides)
cyc = pd.DataFrame(cycles.transform(slides), columns=cycles.get_feature_names_out())
period = cyc["sliding:stick_slip_period [s]"].to_numpy()

fig, axes = plt.subplots(2, 3, figsize=(14, 6), sharex="col")
for j, rec in enumerate(slides):
    taxels = np.column_stack([rec.channel(c) for c in TAXELS])
    axes[0, j].plot(rec.t, taxels - taxels.mean(axis=0), lw=0.5)
    axes[0, j].set_title(f"{rec.name}")
    axes[1, j].plot(rec.t, pc1(taxels), color="0.7", lw=0.6, label="PC1 of taxels")
    axes[1, j].plot(t_fit, y_fit[j], color="C0", lw=1.2, label="PC1, block mean")
    axes[1, j].plot(t_fit, fit.predict(j, t_fit), color="C3", lw=1.5,
                    label=f"contact model, R²={fit.r2[j]:.2f}")
    ticks = np.arange(rec.metadata["ramp_s"], rec.t[-1] - rec.metadata["ramp_s"], period[j])
    axes[1, j].plot(ticks, np.full(ticks.size, axes[1, j].get_ylim()[0]), "|k", ms=8)
    axes[1, j].set(xlabel="time [s]")
    print(f"{rec.metadata['fabric']:8s} fit {fit.model[j]} status {int(fit.status[j])} "
          f"R2 {fit.r2[j]:.3f}  k {fit.values['k'][j]:.3g} 1/mm  tau {fit.values['tau'][j]:.3g} s"
          f"  stick-slip period {period[j]:.2f} s")
axes[0, 0].set_ylabel("taxel - its mean [counts]")
axes[1, 0].set_ylabel("PC1 / its 5-95% range")
axes[1, 0].legend(fontsize=7)
fig.tight_layout()

# %% [markdown]
# ## The fabrics in the physical feature space
# `SlidingPhysicalFeatures` on every slide: texture statistics only (each taxel's own mean
# removed, amplitudes relative to its own range, proximity words never read). Two of its
# quantities against each other, one point per slide: in these two the fabrics overlap
# strongly; the classifiers below use all 158 (mostly per-taxel spectral shape).

# %%
phys = SlidingPhysicalFeatures()
P = pd.DataFrame(phys.fit_transform(recs), columns=phys.get_feature_names_out())
P["fabric"] = meta["fabric"]
x_name, y_name = "sliding:stick_slip_period [mm]", "sliding:slip_asymmetry [1]"
fig, ax = plt.subplots(figsize=(8, 5.5))
for fabric, sub in P.groupby("fabric"):
    ax.scatter(sub[x_name], sub[y_name], s=10, alpha=0.6, label=fabric)
ax.set(xscale="log", xlabel="stick-slip period [mm of travel]", ylabel="slip asymmetry [1]")
ax.legend(fontsize=8, markerscale=2)
print("contact fits converged:", f"{P['sliding:contact_fit_ok [1]'].mean():.2f}",
      "median R2:", f"{P['sliding:contact_fit_r2 [1]'].median():.2f}")
P.groupby("fabric")[[x_name, y_name, "sliding:stick_slip_amplitude [1]"]].median().round(3)

# %% [markdown]
# ## Reproducing the published pipeline
# FFT magnitudes, resampled to 32 points, incremental PCA to D components fitted on the
# training half, distance-weighted 10-NN; stratified random half splits of repetitions 0+1
# (the library's default `norm="global"` reading of the authors' code). Three seeds here;
# the published pipeline's reference is ~0.86 (D=3) / ~0.90 (D=7) over five.

# %%
labels = meta["fabric"].to_numpy()
rows = []
for d in (3, 7):
    for seed in range(3):
        train, test = train_test_split(np.arange(len(recs)), test_size=0.5, stratify=labels,
                                       random_state=seed)
        pipe = Pipeline([("spectral", SpectralPCAFeatures(n_components=d)),
                         ("knn", KNeighborsClassifier(10, weights="distance"))])
        pipe.fit([recs[i] for i in train], labels[train])
        rows.append({"D": d, "seed": seed,
                     "accuracy": pipe.score([recs[i] for i in test], labels[test])})
repro = pd.DataFrame(rows).groupby("D")["accuracy"].agg(["mean", "min", "max"])
repro.round(3)

# %% [markdown]
# ## The warning: a shortcut knows the fabric without any texture
# `shortcut` reads only the static load pattern over the taxels and the proximity words.
# Within one pressure, five fabrics were recorded in one continuous grasp, so a split by
# repetition tests on the grasp it trained on; only leaving a whole pressure out keeps the
# test grasp unseen (250 is outside the training range of the others). Every feature set,
# an RBF SVM, both protocols.

# %%
rows = []
for names in ("shortcut", "spectral", "sliding", "sliding,spectral"):
    for protocol in ("leave-one-repetition-out", "leave-one-pressure-out"):
        ev = evaluate(recs, names, "svm-ovo", protocol, seed=0)
        by_pressure = ev.breakdown.get("pressure")
        row = {"features": names, "protocol": protocol, "accuracy": ev.accuracy}
        if protocol == "leave-one-pressure-out":
            row |= {f"F{p}": a for p, a in by_pressure["accuracy"].items()}
            inside = by_pressure[by_pressure.index.astype(int) <= 210]  # the training range
            row["F120-210"] = (inside["accuracy"] * inside["n"]).sum() / inside["n"].sum()
        rows.append(row)
warning = pd.DataFrame(rows).set_index(["features", "protocol"])
warning.round(3)

# %% [markdown]
# ## What we learned
# The published pipeline reproduces: 0.86 (D=3) and 0.89 (D=7) on random half splits,
# within a point of the reference. The warning is real: the texture-blind `shortcut`
# scores 1.00 by repetition and still 0.97 when a whole pressure is left out (0.97 over
# 120-210), as high as the physical sliding features (`sliding`: 0.98 by repetition, 0.96 over
# 120-210, 0.90 with 250) and above spectra (0.87 over 120-210); at 250, outside the
# training range, texture sets collapse (sliding 0.57, spectral 0.46) while the shortcut
# keeps 0.99, so no texture claim here beats the grasp. The contact model itself explains
# little of a slide: the breakaway fits above reach R² 0.27 at best, and over all slides
# only half converge (median R² 0.22).
