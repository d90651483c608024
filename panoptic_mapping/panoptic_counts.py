"""Bookkeeping of global segments and instances: the triple count Phi(l, c, p) (Eq. 4).

Global segment labels l are merged lazily (a union-find alias), so map regularization never has to
rewrite voxels: lookups canonicalise through `canonical()`.
"""

from __future__ import annotations

from collections import defaultdict

import numpy as np


class PanopticCounts:
    def __init__(self) -> None:
        self.phi: dict[int, dict[tuple[int, int], int]] = defaultdict(dict)
        self.next_label = 1
        self.next_instance = 1
        self.stuff_instance: dict[int, int] = {}
        self._alias = np.zeros(1024, np.int64)  # alias[l] = parent label (0: l is canonical)
        self.last_update: dict[int, int] = {}  # canonical label -> frame index of the last change
        self.instance_frames: dict[int, int] = {}  # instance -> number of segmented frames that saw it
        #: instance -> the most surface (m^2, fronto-parallel: pixels x (z / f)^2) one frame's segments of it
        #: showed: what its entity should own of the map if the map's votes agree with those frames
        self.instance_area: dict[int, float] = {}

    # ------------------------------------------------------------------ labels
    def new_label(self) -> int:
        label = self.next_label
        self.next_label += 1
        if label >= len(self._alias):
            self._alias = np.concatenate([self._alias, np.zeros(len(self._alias), np.int64)])
        return label

    def new_instance(self) -> int:
        p = self.next_instance
        self.next_instance += 1
        return p

    def instance_for_stuff(self, class_id: int) -> int:
        if class_id not in self.stuff_instance:
            self.stuff_instance[class_id] = self.new_instance()
        return self.stuff_instance[class_id]

    def canonical_lut(self, upto: int | None = None) -> np.ndarray:
        """Dense array mapping every label id to its canonical label (0 stays 0)."""
        n = max(upto or 0, self.next_label)
        lut = np.arange(n, dtype=np.int64)
        alias = self._alias[:n]
        if len(alias) < n:
            alias = np.r_[alias, np.zeros(n - len(alias), np.int64)]
        for _ in range(64):  # pointer jumping; merge chains are short
            parent = np.where(alias[lut] > 0, alias[lut], lut)
            if np.array_equal(parent, lut):
                break
            lut = parent
        return lut

    def canonical(self, label: int) -> int:
        while 0 < label < len(self._alias) and self._alias[label] > 0:
            label = int(self._alias[label])
        return label

    def merge_labels(self, src: int, dst: int) -> None:
        """Merge global segment `src` into `dst` (both canonical); counts are added."""
        if src == dst:
            return
        self._alias[src] = dst
        for key, n in self.phi.pop(src, {}).items():
            self.phi[dst][key] = self.phi[dst].get(key, 0) + n
        self.last_update[dst] = max(self.last_update.get(dst, 0), self.last_update.pop(src, 0))

    def merge_instances(self, src: int, dst: int) -> None:
        """Every vote for instance `src` goes to `dst`."""
        self.instance_frames[dst] = self.instance_frames.get(dst, 0) + self.instance_frames.pop(src, 0)
        self.instance_area[dst] = max(self.instance_area.get(dst, 0.0), self.instance_area.pop(src, 0.0))
        for counts in self.phi.values():
            for (c, p) in [k for k in counts if k[1] == src]:
                counts[(c, dst)] = counts.get((c, dst), 0) + counts.pop((c, p))

    # ------------------------------------------------------------------ votes
    def add(self, label: int, class_id: int, instance: int, n: int = 1) -> None:
        """Eq. (4): Phi(l, c, p) += n."""
        counts = self.phi[label]
        counts[(class_id, instance)] = counts.get((class_id, instance), 0) + n

    def instance_votes(self, label: int, class_id: int | None) -> dict[int, int]:
        """Phi(l, c, .) (class given, joint tracking) or sum_c Phi(l, c, .) (class-agnostic)."""
        out: dict[int, int] = {}
        for (c, p), n in self.phi.get(label, {}).items():
            if class_id is None or c == class_id:
                out[p] = out.get(p, 0) + n
        return out

    def segment_class(self, label: int) -> tuple[int, int, int]:
        """Eq. (6) first line: (argmax_c sum_p Phi(l, c, p), its votes, all votes); (-1, 0, 0) if none."""
        per_class: dict[int, int] = {}
        for (c, _p), n in self.phi.get(label, {}).items():
            per_class[c] = per_class.get(c, 0) + n
        if not per_class:
            return -1, 0, 0
        c = max(per_class, key=lambda k: (per_class[k], -k))
        return c, per_class[c], sum(per_class.values())

    # ------------------------------------------------------------------ persistence
    def to_arrays(self) -> dict[str, np.ndarray]:
        rows = [(label, c, p, n) for label, counts in self.phi.items() for (c, p), n in counts.items()]
        return {
            "phi": np.array(rows, np.int64).reshape(-1, 4),
            "alias": self._alias[: self.next_label].copy(),
            "counters": np.array([self.next_label, self.next_instance], np.int64),
            "stuff": np.array(sorted(self.stuff_instance.items()), np.int64).reshape(-1, 2),
            "last_update": np.array(sorted(self.last_update.items()), np.int64).reshape(-1, 2),
            "instance_frames": np.array(sorted(self.instance_frames.items()), np.int64).reshape(-1, 2),
            "instance_area_ids": np.array(sorted(self.instance_area), np.int64),
            "instance_area": np.array([self.instance_area[k] for k in sorted(self.instance_area)], np.float64),
        }

    @classmethod
    def from_arrays(cls, a: dict[str, np.ndarray]) -> PanopticCounts:
        self = cls()
        self.next_label, self.next_instance = (int(v) for v in a["counters"])
        self._alias = np.zeros(max(1024, 2 * self.next_label), np.int64)
        self._alias[: len(a["alias"])] = a["alias"]
        for label, c, p, n in a["phi"]:
            self.phi[int(label)][(int(c), int(p))] = int(n)
        self.stuff_instance = {int(c): int(p) for c, p in a["stuff"]}
        self.last_update = {int(k): int(v) for k, v in a["last_update"]}
        self.instance_frames = {int(k): int(v) for k, v in a.get("instance_frames", np.zeros((0, 2)))}
        self.instance_area = {int(k): float(v) for k, v in zip(a.get("instance_area_ids", np.zeros(0)),
                                                                a.get("instance_area", np.zeros(0)), strict=True)}
        return self
