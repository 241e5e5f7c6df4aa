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

from frictionfit.classify import evaluate, make_pipeline
from frictionfit.datasets import shared_dataset
from frictionfit.datasets.fabricslide import TAXELS, load
from frictionfit.features.grip import grip_load, law_curve, law_support
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
# travel (quarter-sine ramp, then constant speed): the contact law alone. The slide model
# of `SlidingPhysicalFeatures` adds the observable's response to the measured load (the
# grip loop re-commands the gripper during the slide; see below), fits the law to what
# that leaves, and starts from the data (these fits use `fit_trials`' default start, so
# they can differ); the stick-slip period it reports from the steady part's load-free
# spectrum is marked by the ticks.

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
# `SlidingPhysicalFeatures` on every slide, as measured (`grip="none"`) and with the slide
# model's columns (`contact=True`): texture statistics of the taxels without their
# response to the load (each taxel's own mean removed, amplitudes relative to its own
# range, proximity words never read). Two of its quantities against each other, one point
# per slide: in these two the fabrics overlap strongly; the classifiers below use the 150
# texture columns (mostly per-taxel spectral shape), scaled by the grip.

# %%
phys = SlidingPhysicalFeatures(contact=True, grip="none")
P = pd.DataFrame(phys.fit_transform(recs), columns=phys.get_feature_names_out())
P["fabric"] = meta["fabric"]
x_name, y_name = "sliding:stick_slip_period [mm]", "sliding:slip_asymmetry [1]"
fig, ax = plt.subplots(figsize=(8, 5.5))
for fabric, sub in P.groupby("fabric"):
    ax.scatter(sub[x_name], sub[y_name], s=10, alpha=0.6, label=fabric)
ax.set(xscale="log", xlabel="stick-slip period [mm of travel]", ylabel="slip asymmetry [1]")
ax.legend(fontsize=8, markerscale=2)
print("contact fits converged:", f"{P['sliding:contact_fit_ok [1]'].mean():.2f}",
      "median R2 of the slide model:", f"{P['sliding:contact_fit_r2 [1]'].median():.3f}",
      "of the contact law on what the load leaves:",
      f"{P['sliding:contact_law_r2 [1]'].median():.3f}")
P.groupby("fabric")[[x_name, y_name, "sliding:stick_slip_amplitude [1]"]].median().round(3)

# %% [markdown]
# How well the slide model explains the slide, per speed: the median R² of the whole model
# (load response + contact law) on the observable, and of the contact law alone on what
# the load leaves. Most of the observable is the load the grip loop imposes.

# %%
r2 = P.groupby(meta["speed"])[["sliding:contact_fit_r2 [1]", "sliding:contact_law_r2 [1]"]]
print(r2.median().round(3).T.to_string())

# %% [markdown]
# ## The grip as a measured input: scaling laws per fabric
# The grip load of a slide is the trimmed mean of its taxels over the steady part (what
# the grip loop regulates; counts). Three fitted quantities of each slide against it: the
# contact stiffness (the slide model's `k` times the observable's range, counts/mm), the
# texture amplitude (mean log sd of the load-free taxels, counts) and the stick-slip period
# (mm of travel). For each fabric and quantity every grip set-point is left out in turn;
# each candidate law, fitted to the medians at the other grips, predicts the left-out one
# (`law_support`): constant, Hertzian (`L^(1/3)`), per unit load (`L^1`), a free power
# law, or linear. `best` is the law with the fewest parameters within one standard
# error of the smallest held-out error.

# %%
T = P.copy()
T["pressure"], T["speed"] = meta["pressure"], meta["speed"]
T["log_load"] = np.log([grip_load(r) for r in recs])
QUANTITIES = {
    "log stiffness [counts/mm]": T["sliding:log_loading_stiffness [1/mm]"]
    + T["sliding:log_slide_span [counts]"],
    "log texture amplitude [counts]": T["sliding:log_texture_amplitude [counts]"],
    "log stick-slip period [mm]": np.log(T["sliding:stick_slip_period [mm]"]),
}
for name, values in QUANTITIES.items():
    T[name] = values
print("grip load [counts], median per set-point:",
      np.exp(T.groupby("pressure")["log_load"].median()).round(1).to_dict())
support = law_support(T, list(QUANTITIES))
best = support.drop_duplicates(["fabric", "quantity"]).pivot(
    index="fabric", columns="quantity", values="best")
power = support[support["law"] == "power"].pivot(index="fabric", columns="quantity",
                                                 values="exponent")
print("law with the best held-out fit:")
print(best.to_string())
print("exponent of the free power law (all grips):")
print(power.round(2).to_string())
print("held-out rms error, median over fabrics and quantities, by law:")
print(support.groupby("law")["rmse"].median().round(3).to_string())

# %% [markdown]
# The period against load *and* speed, per fabric: `log period[mm] = a + b log L + c log|v|`
# by least squares over every slide. A texture's spatial period does not depend on the
# speed (`c` = 0); a period fixed in time does (`c` = 1).

# %%
rows = []
for fabric, sub in T.groupby("fabric"):
    design = np.column_stack([np.ones(len(sub)), sub["log_load"], np.log(sub["speed"].abs())])
    coef = np.linalg.lstsq(design, sub["log stick-slip period [mm]"], rcond=None)[0]
    rows.append({"fabric": fabric, "b (load)": coef[1], "c (speed)": coef[2]})
pd.DataFrame(rows).set_index("fabric").round(2)

# %% [markdown]
# Each fabric's fitted quantities against its grip, one column per fabric: every slide
# (grey), the median per set-point (black), the law with the best held-out fit (red,
# fitted to all grips of that fabric) and the free power law (dashed).

# %%
fabrics = sorted(T["fabric"].unique())
fig, axes = plt.subplots(len(QUANTITIES), len(fabrics), figsize=(20, 8), sharex=True,
                         sharey="row")
for j, fabric in enumerate(fabrics):
    sub = T[T["fabric"] == fabric]
    med = sub.groupby("pressure")[["log_load", *QUANTITIES]].median()
    grid = np.linspace(np.log(110), np.log(250), 50)
    for i, name in enumerate(QUANTITIES):
        ax = axes[i, j]
        ax.scatter(np.exp(sub["log_load"]), sub[name], s=4, color="0.75")
        ax.plot(np.exp(med["log_load"]), med[name], "ok", ms=4)
        law = best.loc[fabric, name]
        ax.plot(np.exp(grid), law_curve(law, med["log_load"], med[name], grid), "C3",
                label=law)
        ax.plot(np.exp(grid), law_curve("power", med["log_load"], med[name], grid), "--",
                color="C0", lw=0.8)
        ax.set_xscale("log")
        ax.set_xticks([120, 180, 250], ["120", "180", "250"], minor=False)
        ax.minorticks_off()
        ax.legend(fontsize=7, loc="best")
        if j == 0:
            ax.set_ylabel(name, fontsize=8)
        if i == 0:
            ax.set_title(fabric)
        if i == len(QUANTITIES) - 1:
            ax.set_xlabel("grip load [counts]")
fig.tight_layout()

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
# test grasp unseen (120 and 250 lie outside the training range of the others:
# extrapolation). Every feature set, an RBF SVM, both protocols. `sliding` reads its grip
# laws against the stroke shift (the load the slide shifts between the taxels from its
# start to its end ramp, unmoved by a constant offset on a taxel); leaving a pressure out,
# also with the laws against the breakaway shift (`grip="breakaway"`: the shift as the slide
# starts, also offset-free), against the grip load (`grip="scaled"`: the taxels' level,
# which such an offset moves) and with no grip law (`grip="none"`).

# %%
breakaway = make_pipeline("sliding", "svm-ovo", probability=True, grip="breakaway")
scaled = make_pipeline("sliding", "svm-ovo", probability=True, grip="scaled")
unscaled = make_pipeline("sliding", "svm-ovo", probability=True, grip="none")
runs = [(names, protocol, None) for names in ("shortcut", "spectral", "sliding",
                                               "sliding,spectral")
        for protocol in ("leave-one-repetition-out", "leave-one-pressure-out")]
runs.append(("sliding, breakaway law", "leave-one-pressure-out", breakaway))
runs.append(("sliding, grip load law", "leave-one-pressure-out", scaled))
runs.append(("sliding, no grip law", "leave-one-pressure-out", unscaled))
rows = []
for names, protocol, pipeline in runs:
    ev = evaluate(recs, names, "svm-ovo", protocol, seed=0, pipeline=pipeline)
    row = {"features": names, "protocol": protocol, "accuracy": ev.accuracy}
    if protocol == "leave-one-pressure-out":
        by_pressure = ev.breakdown["pressure"]
        row |= {f"F{p}": a for p, a in by_pressure["accuracy"].items()}
        inside = by_pressure.loc[[150, 180, 210]]  # inside the training range
        row["F150-210"] = (inside["accuracy"] * inside["n"]).sum() / inside["n"].sum()
    rows.append(row)
warning = pd.DataFrame(rows).set_index(["features", "protocol"])
warning.round(3)

# %% [markdown]
# ## What we learned
# The published pipeline reproduces: 0.86 (D=3) and 0.89 (D=7) on random half splits.
# Taking the grip as a measured input carries the physical features across grips: leaving
# a pressure out, `sliding` (grip laws against the stroke shift, offset-invariant) scores
# 0.903 at 120 (learned from 150-250) and 0.875 at 250 (learned from 120-210), 0.993-1.000
# in between (0.958 overall). With the laws against the breakaway shift (also
# offset-invariant) 120 falls to 0.826 and 250 rises to 0.917 (0.946 overall); against the
# grip load itself (the taxels' level, which an offset moves) 0.882 at 120 (250: 0.917);
# with no grip law, 120 falls to 0.771 (250: 0.896). The warning stands: the texture-blind
# `shortcut` scores 0.970 leaving a pressure out (0.990 at 250), level with `sliding`, so no
# texture claim here beats the grasp. The slide model explains the slide it is fitted to
# (median R² 0.929-0.962 per speed) mostly through the measured load: the contact law
# explains a median 0.211 of what the load leaves, and 0.21 of the fits end converged.
# Per fabric, the texture amplitude grows with the grip about as a friction-like quantity
# (free exponents 0.65-1.25; per unit load has the best held-out fit for three fabrics, a
# free power law or a line for the others); the contact stiffness follows no contact law
# (free exponents from -4.6 to 2.37; constant or a free power law best, Hertzian for none);
# the stick-slip period in mm is constant in the grip for five fabrics, and against the
# speed it is neither fixed in space nor in time (speed exponents -0.03 to 0.75).
