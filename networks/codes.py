"""Marker IDs from code modules: a `MarkerModuleReader`'s logits matched against the codebook.

The reader gives a logit z_m per code module m of the crop (sigmoid: the probability that the
module is filled).  The log-likelihood of a candidate grid with bits b_m, as +-1 values s_m = 2 b_m - 1,
is ``sum_m log sigmoid(s_m z_m) = 0.5 * z . s - sum_m log(2 cosh(z_m / 2))``; the last term is the
same for every candidate, so ``score = 0.5 * z . s`` ranks them, and a softmax over the scores is
their posterior under a uniform prior.  Every candidate ID is scored under its four rotations
(`assets.pattern.rotations`: rotation k is its grid turned k x 90 degrees counter-clockwise, what a
crop shows when its five points are turned by that much) with one matrix product, as the codebook's
own distance check does; the IDs' posteriors sum over the rotations.

The codebook is whatever the pattern prints (any size); the candidates may be restricted to a
garment's IDs.  Nothing here was trained on IDs, so a garment never seen in training is read as well
as one that was.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from assets.pattern.codebook import rotations


def module_targets(codebook: np.ndarray) -> torch.Tensor:
    """(num_ids, n, n) uint8 module grids -> (num_ids, n * n) float32 in {0, 1}: row k is marker ID k's
    grid in its canonical orientation, row-major (the `MarkerModuleReader`'s output order)."""
    codebook = np.asarray(codebook)
    if codebook.ndim != 3 or codebook.shape[1] != codebook.shape[2]:
        raise ValueError(f"module_targets: expected module grids (num_ids, n, n), got shape {codebook.shape}")
    return torch.as_tensor(codebook.reshape(len(codebook), -1) != 0, dtype=torch.float32)


def signed_rotations(codes: np.ndarray) -> np.ndarray:
    """(K, n, n) binary module grids -> (K, 4, n * n) float32 +-1 vectors of each grid turned by
    0, 90, 180 and 270 degrees counter-clockwise."""
    codes = np.asarray(codes)
    return (rotations(codes != 0).reshape(len(codes), 4, -1).astype(np.float32) * 2.0) - 1.0


@dataclass(frozen=True)
class CodeReading:
    """What `CodeDecoder.decode` reads from B crops (tensors on the decoder's device).

    marker_id (B,) int64: the most probable candidate ID; probability (B,) float32: its posterior
    among the candidates (summed over its rotations); rotation (B,) int64 in 0..3: the rotation of
    that ID that scores best; margin (B,) float32: its best score minus the best score of any other
    ID (log-likelihood ratio, nats; large when the reading is unambiguous)."""

    marker_id: torch.Tensor
    probability: torch.Tensor
    rotation: torch.Tensor
    margin: torch.Tensor


class CodeDecoder:
    """Scores module logits against the candidate IDs of a codebook under all four rotations.

    codebook: (num_ids, n, n) module grids of the pattern (`assets.pattern.generate_codebook`; any
    size).  marker_ids: the candidate IDs (e.g. a garment's), default every ID of the codebook.  The
    candidates' +-1 vectors are kept on `device` as one (n * n, K * 4) matrix.
    """

    def __init__(self, codebook: np.ndarray, marker_ids: np.ndarray | None = None,
                 device: str | torch.device = "cpu") -> None:
        codebook = np.asarray(codebook)
        if codebook.ndim != 3 or codebook.shape[1] != codebook.shape[2] or len(codebook) < 1:
            raise ValueError(f"CodeDecoder: expected a codebook of module grids (num_ids, n, n), got shape "
                             f"{codebook.shape}")
        ids = np.arange(len(codebook)) if marker_ids is None else np.unique(np.asarray(marker_ids, dtype=np.int64))
        if ids.ndim != 1 or len(ids) < 1 or ids.min() < 0 or ids.max() >= len(codebook):
            raise ValueError(f"CodeDecoder: marker_ids must be a non-empty list of IDs in 0..{len(codebook) - 1}")
        self.modules_per_side = int(codebook.shape[1])
        self.marker_ids = ids
        self.device = torch.device(device)
        signed = signed_rotations(codebook[ids]).reshape(len(ids) * 4, -1)
        self._signed = torch.as_tensor(signed.T.copy(), device=self.device)  # (L, K * 4)
        self._ids = torch.as_tensor(ids, device=self.device)
        #: (num_ids,) int64: the candidate index of each codebook ID, -1 for the others
        index = np.full(len(codebook), -1, dtype=np.int64)
        index[ids] = np.arange(len(ids))
        self._index = torch.as_tensor(index, device=self.device)

    def scores(self, logits: torch.Tensor) -> torch.Tensor:
        """Module logits (B, n * n) -> log-likelihood scores (B, K, 4) float32 of each candidate ID
        (`marker_ids` order) under each rotation, up to a constant per crop."""
        length = self.modules_per_side ** 2
        if logits.ndim != 2 or logits.shape[1] != length:
            raise ValueError(f"CodeDecoder: expected module logits (B, {length}), got {tuple(logits.shape)}")
        return (0.5 * (logits.float().to(self.device) @ self._signed)).view(len(logits), -1, 4)

    def _posteriors(self, logits: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(scores (B, K, 4), log posterior of each candidate ID (B, K), rotations summed)."""
        scores = self.scores(logits)
        return scores, torch.log_softmax(torch.logsumexp(scores, dim=2), dim=1)

    def decode(self, logits: torch.Tensor) -> CodeReading:
        """The best candidate ID of each crop, its posterior, rotation and margin (`CodeReading`)."""
        scores, log_posterior = self._posteriors(logits)
        log_best, index = log_posterior.max(dim=1)
        per_id = scores.max(dim=2)
        rows = torch.arange(len(index), device=self.device)
        rotation = per_id.indices[rows, index]
        best = per_id.values[rows, index]
        others = per_id.values.clone()
        others[rows, index] = -torch.inf
        margin = best - others.max(dim=1).values  # inf with a single candidate
        return CodeReading(self._ids[index], log_best.exp(), rotation, margin)

    def probability_of(self, logits: torch.Tensor, marker_id: torch.Tensor | np.ndarray) -> torch.Tensor:
        """(B,) float32 posterior of the given `marker_id` (B,) of each crop among the candidates; 0 for an
        ID that is not a candidate."""
        _, log_posterior = self._posteriors(logits)
        ids = torch.as_tensor(np.asarray(marker_id, dtype=np.int64), device=self.device)
        if ids.shape != (len(logits),):
            raise ValueError(f"CodeDecoder.probability_of: expected {len(logits)} IDs, got shape {tuple(ids.shape)}")
        inside = (ids >= 0) & (ids < len(self._index))
        index = self._index[torch.where(inside, ids, 0)]
        known = inside & (index >= 0)
        picked = log_posterior.gather(1, index.clamp(min=0)[:, None])[:, 0].exp()
        return torch.where(known, picked, torch.zeros_like(picked))

    def ranked(self, logits: torch.Tensor, k: int = 5) -> torch.Tensor:
        """(B, min(k, K)) int64 candidate IDs of each crop, most probable first."""
        _, log_posterior = self._posteriors(logits)
        return self._ids[torch.topk(log_posterior, min(k, log_posterior.shape[1]), dim=1).indices]
