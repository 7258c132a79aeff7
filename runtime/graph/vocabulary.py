"""A flat visual vocabulary with tf-idf weights: which stored views of a map hold the appearance of a new
image (place recognition for `runtime.graph.relocalize`; DBoW's idea, without its tree)."""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from runtime.graph.factors import GraphError


def descriptor_vectors(desc: np.ndarray) -> np.ndarray:
    """(N,D) float32 unit vectors of descriptors: float descriptors normalised, binary (uint8) ones
    unpacked to +-1 bits, so that a dot product ranks them as their own distance does."""
    d = np.asarray(desc)
    if np.issubdtype(d.dtype, np.floating):
        v = d.astype(np.float32)
    else:
        v = np.unpackbits(d.astype(np.uint8), axis=1).astype(np.float32) * 2.0 - 1.0
    n = np.linalg.norm(v, axis=1, keepdims=True)
    return v / np.maximum(n, 1e-12)


class Vocabulary:
    """A flat visual vocabulary with tf-idf weights: `histogram` turns a view's descriptors into a unit
    vector; the dot product of two ranks how much of one image's appearance the other holds."""

    def __init__(self, centres: np.ndarray, idf: np.ndarray) -> None:
        self.centres = np.asarray(centres, np.float32)
        self.idf = np.asarray(idf, np.float32)

    @classmethod
    def train(cls, descriptors: Sequence[np.ndarray], words: int = 256, seed: int = 0,
              max_samples: int = 40_000) -> Vocabulary:
        """k-means (OpenCV, k-means++ seeding) of up to `max_samples` descriptors drawn from every view,
        then idf_w = log(views / views holding word w)."""
        import cv2

        vecs = [descriptor_vectors(d) for d in descriptors if len(d)]
        if not vecs:
            raise GraphError("no descriptors to build a vocabulary from")
        allv = np.concatenate(vecs)
        rng = np.random.default_rng(seed)
        if len(allv) > max_samples:
            allv = allv[rng.choice(len(allv), max_samples, replace=False)]
        k = int(min(words, len(allv)))
        cv2.setRNGSeed(int(seed))
        crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 20, 1e-4)
        _, _, centres = cv2.kmeans(allv, k, None, crit, 1, cv2.KMEANS_PP_CENTERS)
        centres /= np.maximum(np.linalg.norm(centres, axis=1, keepdims=True), 1e-12)
        voc = cls(centres, np.ones(k, np.float32))
        holds = np.zeros(k)
        for v in vecs:
            holds[np.unique(voc.words_of(v))] += 1
        voc.idf = np.log(len(vecs) / np.maximum(holds, 1.0)).astype(np.float32)
        return voc

    def words_of(self, vectors: np.ndarray) -> np.ndarray:
        """(N,) index of the nearest word of each unit vector (largest dot product)."""
        return np.argmax(vectors @ self.centres.T, axis=1)

    def histogram(self, desc: np.ndarray) -> np.ndarray:
        """(W,) tf-idf histogram of one view's descriptors, L2-normalised (zeros when it has none)."""
        h = np.zeros(len(self.centres), np.float32)
        if len(desc):
            np.add.at(h, self.words_of(descriptor_vectors(desc)), 1.0)
            h *= self.idf / len(desc)
        n = float(np.linalg.norm(h))
        return h / n if n > 0 else h
