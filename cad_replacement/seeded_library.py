"""A ``CadLibrary`` whose procedural seeds are listed per class (benchmarks: in-library vs unseen).

``CadLibrary`` enumerates seeds ``0 .. seeds_per_class - 1``; evaluating CAD replacement needs
libraries that do (in-library) or do not (unseen) contain the exact models of a scene, whose seeds
are arbitrary integers. Imported models and the feature cache work as in ``CadLibrary``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

from cad_replacement.cad.library import CadEntry, CadLibrary
from cad_replacement.cad.procedural import procedural_model_id


@dataclass
class SeededLibrary(CadLibrary):
    """``CadLibrary`` plus ``extra_seeds`` (class -> seeds) and minus ``exclude_seeds``."""

    extra_seeds: Mapping[str, Sequence[int]] = field(default_factory=dict)
    exclude_seeds: Mapping[str, Sequence[int]] = field(default_factory=dict)

    def _scan(self) -> list[CadEntry]:
        entries = super()._scan()
        excluded = {(c, int(s)) for c, seeds in self.exclude_seeds.items() for s in seeds}
        have = {(e.class_name, e.seed) for e in entries if e.kind == "procedural"}
        for cls in self._procedural_classes:
            for s in self.extra_seeds.get(cls, ()):
                if (cls, int(s)) not in have:
                    have.add((cls, int(s)))
                    entries.append(
                        CadEntry(f"procedural/{cls}/{procedural_model_id(cls, int(s))}", cls, "procedural", seed=int(s))
                    )
        return [e for e in entries if e.kind != "procedural" or (e.class_name, e.seed) not in excluded]


__all__ = ["SeededLibrary"]
