"""Where each body's entries sit in one global state (numpy only; the counts come from the caller).

Several bodies share one global vector. Each rank owns a contiguous range of it, and within that
range the entries each body owns on this rank, body after body::

    rank 0: [body 0 on rank 0 | body 1 on rank 0 | ...]  rank 1: [body 0 on rank 1 | body 1 on rank 1 | ...]

So a body's owned entries on a rank are one slice of that rank's part of the global vector (no
scatter between a body's vector and the stacked one), and one body keeps its own numbering
exactly. :class:`StackedLayout` maps a body's global indices (its own numbering: rank ``p`` owns
``[body_start[b, p], body_start[b, p + 1])``) to stacked global indices. The same class serves
blocks (3 DOFs each) and DOFs.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


def body_array_name(name: str, body: int, bodies: int) -> str:
    """A checkpoint array's name for body ``body`` of ``bodies``: one body's as a run of one body
    names it, several bodies' numbered (``position_dofs_1``)."""
    return name if bodies == 1 else f"{name}_{body}"


class StackedLayout:
    """Stacked global numbering of several bodies' entries.

    Args:
        owned: ``owned[p][b]``, entries body ``b`` owns on rank ``p``, shape ``(ranks, bodies)``.
        rank: this rank.

    Raises:
        ValueError: counts that are negative or not a 2-D table, or a rank outside it.
    """

    def __init__(self, owned: Sequence[Sequence[int]] | np.ndarray, rank: int):
        counts = np.asarray(owned, dtype=np.int64)
        if counts.ndim != 2 or counts.shape[1] < 1 or (counts < 0).any():
            raise ValueError(f"owned counts must be a (ranks, bodies) table of counts >= 0, got {counts.tolist()}")
        if not 0 <= rank < counts.shape[0]:
            raise ValueError(f"rank {rank} is not one of the table's {counts.shape[0]} ranks")
        self.owned = counts
        self.rank = rank
        #: stacked global index where each rank's range starts, ``(ranks + 1,)``
        self.rank_start = np.concatenate([[0], np.cumsum(counts.sum(axis=1))])
        #: offset of each body within each rank's range, ``(ranks, bodies)``
        self.body_offset = np.concatenate([np.zeros((counts.shape[0], 1), np.int64), np.cumsum(counts, axis=1)[:, :-1]],
                                          axis=1)  # fmt: skip
        #: each body's own global numbering: where each rank's part starts, ``(bodies, ranks + 1)``
        self.body_start = np.concatenate([np.zeros((counts.shape[1], 1), np.int64), np.cumsum(counts.T, axis=1)],
                                         axis=1)  # fmt: skip

    @property
    def bodies(self) -> int:
        return self.owned.shape[1]

    @property
    def size_local(self) -> int:
        """Entries this rank owns (all bodies)."""
        return int(self.owned[self.rank].sum())

    @property
    def size_global(self) -> int:
        return int(self.rank_start[-1])

    def local_slice(self, body: int) -> slice:
        """Where ``body``'s owned entries sit in this rank's part of the stacked vector."""
        start = int(self.body_offset[self.rank, body])
        return slice(start, start + int(self.owned[self.rank, body]))

    def body_size_global(self, body: int) -> int:
        return int(self.body_start[body, -1])

    def to_stacked(self, body: int, indices: np.ndarray) -> np.ndarray:
        """Stacked global indices of ``body``'s global indices ``indices`` (any shape, any owner).

        Raises:
            IndexError: an index outside the body's range.
        """
        indices = np.asarray(indices, dtype=np.int64)
        starts = self.body_start[body]
        if indices.size and (indices.min() < 0 or indices.max() >= starts[-1]):
            raise IndexError(f"body {body} has {starts[-1]} entries; indices span [{indices.min()}, {indices.max()}]")
        owner = np.searchsorted(starts, indices, side="right") - 1
        return self.rank_start[owner] + self.body_offset[owner, body] + indices - starts[owner]

    def to_body(self, indices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The inverse of :meth:`to_stacked`: ``(body, body-global index)`` of stacked global indices."""
        indices = np.asarray(indices, dtype=np.int64)
        if indices.size and (indices.min() < 0 or indices.max() >= self.size_global):
            raise IndexError(f"the stacked layout has {self.size_global} entries; indices span "
                             f"[{indices.min()}, {indices.max()}]")  # fmt: skip
        owner = np.searchsorted(self.rank_start, indices, side="right") - 1
        within = indices - self.rank_start[owner]
        body = self._body_of(owner, within)
        return body, self.body_start[body, owner] + within - self.body_offset[owner, body]

    def _body_of(self, owner: np.ndarray, within: np.ndarray) -> np.ndarray:
        """The body each ``within``-th entry of rank ``owner``'s range belongs to (empty bodies skipped)."""
        ends = self.body_offset[owner] + self.owned[owner]  # (..., bodies): where each body's slice ends
        return (within[..., None] >= ends).sum(axis=-1)
