# ---
# jupyter:
#   jupytext:
#     formats: ipynb,py:percent
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
# # 03 — Classify materials: every feature set side by side
#
# **Question:** which feature set recognises a material measured on another day best,
# which classes does each confuse, and what does the SVM on the physical features
# actually rely on?
#
# To stay quick we take 12 of the 35 simulated classes, chosen to include the
# deliberately close pairs (the two curtains, paper and banknote, PE bag and cling film),
# each with one and two layers, three measurements per class in each of two sessions.
# The protocol is leave-one-session-out: train on one day, test on the other.

# %%
import time

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
from sklearn.inspection import permutation_importance
from sklearn.metrics import ConfusionMatrixDisplay
from sklearn.pipeline import make_pipeline as sk_pipeline
from sklearn.preprocessing import StandardScaler

from frictionfit.classify import evaluate, make_classifier, make_pipeline, projection_for
from frictionfit.features import make_features
from frictionfit.simulation.measurements import simulate_measurements

MATERIALS = ("curtain-rose", "curtain-white", "paper", "banknote", "pe-bag", "saran-wrap")
CLASSES = [f"{m}-{layers}" for m in MATERIALS for layers in (1, 2)]
specs = [(session, label, trial) for session in (1, 2) for label in CLASSES
         for trial in (1, 2, 3)]
recs = simulate_measurements(specs, seed=3)
print(len(recs), "measurements of", len(CLASSES), "classes in 2 sessions")

# %% [markdown]
# ## Every feature set, the same protocol
# `physical` is, by default, the model-free contact quantities measured per phase and
# channel, with the gain-free shape quantities (slip ripple, normalised relaxation
# curve); `fitted` is the contact law's parameters alone, from one whole-measurement fit
# per recording of each channel along the rubbing direction (`thumb_x`, `index_x`: rig,
# sensor and law fitted once each), and each lateral channel's law on its finger's fitted
# force (`thumb_y`, `index_y`: the lateral share and its stick-slip); `physical (all)` is
# both (`fitted=True`). The data span two sessions, so `evaluate` asks for the LDA
# projection between the scaler and the SVM (`projection_for`), but one training day of 36
# recordings in 12 classes leaves 24 degrees of freedom for the within-class covariance:
# enough for the 22 features of `fitted` alone (`physical` has 88, `handcrafted` 40), so
# for every other set the projection steps aside (`DiscriminantProjection`; the cell
# after the table counts them).
# Rows are cached by recording content, so the second fold and the later cells reuse them.

# %%
# (`relaxation=True`: the relaxation quantities too, which one rig's recordings can use)
FEATURE_SETS = {"physical": make_pipeline("physical", relaxation=True,
                                          project=projection_for(recs)),
                "fitted": make_pipeline("fitted", relaxation=True, project=projection_for(recs)),
                "physical (all)": make_pipeline("physical", fitted=True, relaxation=True,
                                                project="lda"),
                "handcrafted": None, "fftbins": None, "raw": None,
                "physical,handcrafted": make_pipeline("physical,handcrafted", "svm-ovo", seed=0,
                                                      relaxation=True, probability=True,
                                                      project=projection_for(recs))}
results, rows = {}, []
for names, pipeline in FEATURE_SETS.items():
    start = time.perf_counter()
    ev = evaluate(recs, names, "svm-ovo", "leave-one-session-out", seed=0, pipeline=pipeline)
    results[names] = ev
    rows.append({"features": names, "accuracy": ev.accuracy, "macro_f1": ev.macro_f1,
                 "fold accuracies": np.round(ev.fold_accuracy, 3).tolist(),
                 "layers right": ev.derived_accuracy("layers", recs),
                 "material right": ev.derived_accuracy("material", recs),
                 "seconds": time.perf_counter() - start})
table = pd.DataFrame(rows).set_index("features")
table.round(3)

# %%
# the feature counts behind the projection's choice, on one training day
train_recs = [r for r in recs if r.metadata["session"] == 1]
dof = len(train_recs) - len(CLASSES)
for names in FEATURE_SETS:
    features = (make_features("physical", fitted=True, relaxation=True)
                if names == "physical (all)" else make_features(names, relaxation=True))
    p = features.fit_transform(train_recs).shape[1]
    print(f"{names}: {p} features, LDA projection {'used' if dof > p else 'steps aside'}")
print(f"{len(train_recs)} training recordings - {len(CLASSES)} classes = {dof} degrees of freedom")

# %% [markdown]
# ## Confusion matrices
# Rows are the true class, columns the predicted one (pooled over both test sessions).

# %%
fig, axes = plt.subplots(1, 2, figsize=(13, 5.5))
best_other = table.drop(index=["physical", "fitted", "physical (all)"])["accuracy"].idxmax()
for ax, names in zip(axes, ("physical (all)", best_other), strict=True):
    cm = results[names].confusion
    ConfusionMatrixDisplay(cm.to_numpy(), display_labels=cm.index).plot(
        ax=ax, colorbar=False, xticks_rotation=90)
    ax.set_title(f"{names}: accuracy {results[names].accuracy:.2f}")
fig.tight_layout()
for names in ("physical (all)", best_other):
    cm = results[names].confusion
    off = cm.to_numpy() - np.diag(np.diag(cm.to_numpy()))
    worst = np.dstack(np.unravel_index(np.argsort(off, axis=None)[::-1][:3], off.shape))[0]
    print(names, "most confused:",
          [(cm.index[i], cm.columns[j], int(off[i, j])) for i, j in worst if off[i, j]])

# %%
# how many of the errors fall inside the designed look-alike pairs (either layer count)
PAIRS = {("curtain-rose", "curtain-white"), ("paper", "banknote"), ("pe-bag", "saran-wrap")}
for names in ("physical (all)", best_other):
    cm = results[names].confusion
    true_m, pred_m = cm.index.str.rsplit("-", n=1).str[0], cm.columns.str.rsplit("-", n=1).str[0]
    off = cm.to_numpy() - np.diag(np.diag(cm.to_numpy()))
    in_pair = np.array([[(a, b) in PAIRS or (b, a) in PAIRS for b in pred_m] for a in true_m])
    print(f"{names}: {off.sum()} errors, {off[in_pair].sum()} inside the designed pairs")

# %% [markdown]
# ## What does the SVM rely on? Permutation importance on the physical features
# All physical features (fits and shape quantities, cached above) are standardised within
# each session; the scaler and SVM are trained on session 1, and each feature is
# shuffled in turn on session 2: the drop in accuracy is that feature's importance. We
# sum the importances over the four channels.

# %%
phys = make_features("physical", fitted=True, relaxation=True)
X = pd.DataFrame(phys.fit_transform(recs), columns=phys.get_feature_names_out())
session = np.array([r.metadata["session"] for r in recs])
labels = np.array([r.metadata["label"] for r in recs])
Xz = X.groupby(session).transform(lambda c: (c - c.mean()) / (c.std(ddof=0) + 1e-12))
train, test = session == 1, session == 2
svm = sk_pipeline(StandardScaler(), make_classifier("svm-ovo")).fit(Xz[train], labels[train])
print(f"session 1 -> 2 accuracy: {svm.score(Xz[test], labels[test]):.3f}")
imp = permutation_importance(svm, Xz[test], labels[test], n_repeats=5, random_state=0)
per_feature = pd.Series(imp.importances_mean, index=X.columns)
quantity = per_feature.index.str.split(":").str[1]
by_quantity = per_feature.groupby(quantity).sum().sort_values(ascending=False)
ax = by_quantity.head(15)[::-1].plot.barh(figsize=(7, 5))
ax.set(xlabel="accuracy drop when shuffled (summed over channels)",
       title="What the SVM relies on (physical features)")
by_quantity.head(10).round(3)

# %% [markdown]
# ## How sure is each call? Calibrated probabilities, and a damaged recording
# `evaluate` (above) and `frictionfit predict` give every recording a probability per
# class: the SVM's own (Platt) probabilities, recalibrated by temperature scaling on
# recordings held out of training (other sessions where there are several; here, with
# one training session per fold, stratified folds of it). With `n_draws`, each
# recording's probabilities are averaged over draws of its features (a bootstrap over
# its motions; a quantity no motion gives is drawn from the training values), so a
# recording whose motions disagree or are damaged gets a flatter distribution. We damage
# one test recording (30 % of its samples lost in bursts of 20-200 samples, as a failing
# serial link does) and compare it with its intact twin, each predicted with the rest of
# its session intact.

# %%
from frictionfit.calibration import CalibratedPipeline, expected_calibration_error
from frictionfit.recording import Recording

ev = results["physical"]
print(f"physical, leave-one-session-out: accuracy {ev.accuracy:.3f}, "
      f"ECE {expected_calibration_error(ev.predictions['probability'], ev.correct):.3f}")
train = [r for r in recs if r.metadata["session"] == 1]
test = [r for r in recs if r.metadata["session"] == 2]
model = CalibratedPipeline(make_pipeline("physical", probability=True, relaxation=True),
                           n_draws=32).fit(
    train, [r.metadata["label"] for r in train])

rng = np.random.default_rng(0)
intact_all = model.predict_proba(test)
i = int(np.argmax(intact_all.max(axis=1)))  # the surest call of session 2
target = test[i]
gone = np.zeros(target.samples.shape[0], dtype=bool)
while gone.mean() < 0.3:
    start = rng.integers(0, gone.size)
    gone[start:start + rng.integers(20, 200)] = True
damaged_samples = target.samples.copy()
damaged_samples[gone] = np.nan
damaged = Recording.from_arrays(damaged_samples, target.sample_rate_hz, target.channel_names,
                                events=target.events, name=target.name + " (damaged)",
                                metadata=target.metadata)
intact = intact_all[i]
hurt = model.predict_proba([*test[:i], damaged, *test[i + 1:]])[i]
spread = pd.DataFrame({"intact": intact, "damaged": hurt}, index=model.classes_)
top = spread.loc[spread.max(axis=1).sort_values(ascending=False).index[:6]]
ax = top.plot.bar(figsize=(8, 3.5), rot=30)
ax.set(ylabel="probability", title=f"{target.name}: true class {target.metadata['label']}")
top.round(3)

# %% [markdown]
# The draws behind it: two of the measured quantities of the index channel, one point per
# draw, for the intact recording and its damaged twin.

# %%
features = model.pipeline_["features"]
names = list(features.get_feature_names_out())
cols = [names.index("index_x:out_rise [N]"), names.index("index_x:out_relaxed_frac [1]")]
fig, ax = plt.subplots(figsize=(5, 4))
for rec, colour in ((target, "tab:blue"), (damaged, "tab:red")):
    draws = features.transform_draws([*test[:i], rec, *test[i + 1:]], 200,
                                     np.random.default_rng(1))[:, i]
    ax.scatter(draws[:, cols[0]], draws[:, cols[1]], s=8, alpha=0.4, color=colour,
               label=rec.name)
ax.set(xlabel="index_x out rise (standardised)", ylabel="index_x out relaxed fraction "
       "(standardised)", title="feature draws")
ax.legend(fontsize=8)

# %% [markdown]
# ## A doubtful fit: its posterior, and the class probabilities it spreads
# Each fitted feature comes with its whole fit's standard error. With draws, the classifier
# sees every fitted value drawn from its fit's posterior (normal about the value); a value
# less certain than the spread of that feature over the training recordings tells them
# apart no better than chance and is drawn from the training values instead. We take the
# session-2 recording whose fitted values are least certain against that spread, look at
# its fit, and compare its class probabilities from point values and from 64 draws.

# %%
import frictionfit
from frictionfit.features.physical import FittedFeatures

labels = [r.metadata["label"] for r in train]
# the rows the fits above stored
with_errors = FittedFeatures(with_stderr=True, relaxation=True).fit(train)
names = list(with_errors.get_feature_names_out())
values = [n for n in names if "_stderr" not in n]
errors = [n for n in names if "_stderr" in n]
cells = pd.DataFrame(with_errors.transform(test), columns=names)
spread = pd.DataFrame(with_errors.training_rows_, columns=names)[values].std().to_numpy()
doubt = np.nanmedian(cells[errors].to_numpy() / spread, axis=1)  # stderr / training spread
j = int(np.argmax(doubt))
doubtful = test[j]
print(f"{doubtful.name}: median stderr / training spread {doubt[j]:.2f} "
      f"(session 2 median {np.median(doubt):.2f})")
fit = frictionfit.fit_recordings(doubtful, channels=["index_x"], model="relaxation2",
                                 fix={"wear": 0.0}, max_steps=200, creep="recording",
                                 progress=False)  # as the features fit
print(fit.report(0))

# %%
fitted_pipeline = make_pipeline("fitted", probability=True, relaxation=True)
point = CalibratedPipeline(fitted_pipeline, n_draws=0).fit(train, labels)
drawn = CalibratedPipeline(fitted_pipeline, n_draws=64).fit(train, labels)
probabilities = pd.DataFrame({"point values": point.predict_proba(test)[j],
                              "posterior draws": drawn.predict_proba(test)[j]},
                             index=point.classes_)
top = probabilities.loc[probabilities.max(axis=1).sort_values(ascending=False).index[:6]]
ax = top.plot.bar(figsize=(8, 3.5), rot=30)
ax.set(ylabel="probability", title=f"{doubtful.name}: true class "
       f"{doubtful.metadata['label']}, fitted features only")
top.round(3)

# %% [markdown]
# ## What we learned
# Trained on one day and tested on the other, on 12 deliberately close classes, the fitted
# contact law alone (`fitted`: stiffness, static friction level, held and peak force,
# onset rate, stick-slip intensity, relaxation and drag of the two rubbing channels, each
# recording fitted whole, and each lateral channel's share of the fitted force and its
# stick-slip) scores best, 0.63 (folds 0.53 / 0.72), then the measured contact
# quantities (`physical`) 0.58 (0.56 / 0.61), all physical features together 0.56 (0.53
# / 0.58) and the measured quantities with the handcrafted ones 0.53 (0.44 / 0.61), all
# ahead of handcrafted (0.35), FFT bins (0.31) and raw signals (0.15). The layer count
# is right for nearly every recording (1.00 for every set but `fitted` 0.99, FFT bins
# 0.97 and raw signals 0.86). Most errors fall inside the designed look-alike pairs (22
# of 32 with all physical features, 26 of 34 with `physical,handcrafted`), above all
# curtain-rose-1 called curtain-white-1 (6 of 6 in one direction) and curtain-white-2
# vs curtain-rose-2; the two-layer PE bag goes to paper-2 (4). No single quantity carries
# the SVM on all physical features (session 1 -> 2 accuracy 0.583): shuffling the
# stick-slip ripple of the back or the out stroke costs 0.061 and 0.056 of its accuracy,
# the strokes' peak times 0.028 each, and the fitted relaxation fraction, gain and
# stiffness 0.022, 0.017 and 0.011. The command line classifies rubbing recordings with
# both (`physical,fitted`) unless told otherwise, a choice made on the lab stand-in,
# whose physics is not the model's and which has more training days (see
# `docs/results.md`). With one training day the LDA projection steps aside for every set
# but `fitted` (too few rows).
#
# The class probabilities are only as good as what they are calibrated on: with one
# training day of three recordings per class, each inner pipeline of the calibration
# learns a class from two recordings, its held-out calls are poorer than the final
# pipeline's, and the probabilities come out too flat (expected calibration error 0.27).
# The surest call of session 2 is still a confident error: a curtain-rose-2 recording
# called curtain-white-2 at 0.66 (its true class 0.16). Once 30 % of its samples are
# lost that probability drops to 0.38 (the true class 0.16), and its motions' draws
# spread out: the damage shows in the probability instead of hiding in a confident label.
#
# The least certain fit of session 2 (s2_pe-bag-1_02, standard errors 0.40 of the spread
# between training recordings, against 0.16 for the median recording) fits its index
# channel well (R-squared 0.999), but its stiffness is not identified (29 +- 30 N/mm):
# it trades with the motor's acceleration share (correlation +0.99), and its slow
# relaxation branch sits at its 100-s bound. Its fitted features still point to the true
# class: from point values pe-bag-1 0.19, banknote-1 0.16, saran-wrap-1 0.13; drawn from
# that posterior, pe-bag-1 0.21, saran-wrap-1 0.15, banknote-1 0.11: the true class stays
# first, with a low top probability that `--abstain` turns into no call.
