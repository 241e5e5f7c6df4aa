"""The shortcut control: features that identify a FabricSlide fabric without any texture.

Every fabric in FabricSlide is one mounting and one block of recording time, so the
static load pattern over the taxels and the two "proximity" words tell the fabric
apart without looking at texture (see the dataset's README). Results tables show
this set beside the texture sets as a warning: a texture classifier is only
convincing where it beats this control on splits that keep test grasps out of
training (leave one pressure out).

=========================  =====  ==================================================
feature                    unit   definition
=========================  =====  ==================================================
``load_share:channel<i>``  1      mean of taxel ``i`` / mean over all taxels (16)
``proximity<j>:mean``      counts mean of proximity word ``j`` (2)
``proximity<j>:sd``        counts standard deviation of proximity word ``j`` (2)
=========================  =====  ==================================================
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from frictionfit.datasets.fabricslide import PROXIMITY, TAXELS
from frictionfit.errors import RecordingError
from frictionfit.features._base import RecordingFeatures
from frictionfit.recording import Recording

__all__ = ["ShortcutFeatures", "shortcut_features"]


def shortcut_features(rec: Recording) -> np.ndarray:
    """The 20 shortcut values of one FabricSlide recording (see the module table).

    Raises
    ------
    RecordingError
        When a taxel or proximity channel is missing, or the taxels' mean load is not positive.
    """
    taxels = np.column_stack([rec.channel(c) for c in TAXELS]).mean(axis=0)
    total = taxels.mean()
    if not total > 0:
        raise RecordingError(f"mean taxel load {total:.3g} counts is not positive", path=rec.name)
    prox = np.column_stack([rec.channel(c) for c in PROXIMITY])
    return np.concatenate([taxels / total, prox.mean(axis=0), prox.std(axis=0)])


class ShortcutFeatures(RecordingFeatures):
    """Static taxel load shares and proximity statistics: the non-texture control.

    Parameters
    ----------
    cache : bool, default True
        Cache rows per recording content (see :mod:`frictionfit.features._base`).

    Examples
    --------
    >>> ShortcutFeatures().get_feature_names_out()[[0, 16, 18]].tolist()
    ['shortcut:load_share:channel1 [1]', 'shortcut:proximity1:mean [counts]', \
'shortcut:proximity1:sd [counts]']
    """

    def __init__(self, cache: bool = True):
        self.cache = cache

    def _extract(self, recordings: Sequence[Recording]) -> np.ndarray:
        return np.vstack([shortcut_features(r) for r in recordings])

    def _names(self) -> list[str]:
        return ([f"shortcut:load_share:{c} [1]" for c in TAXELS]
                + [f"shortcut:{p}:mean [counts]" for p in PROXIMITY]
                + [f"shortcut:{p}:sd [counts]" for p in PROXIMITY])
