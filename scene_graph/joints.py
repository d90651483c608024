"""Which joint a support edge becomes in the kinematic tree (paper Sec. 4.5).

"A cup is connected to a table using a floating joint as a robot can freely manipulate it, and a
table is linked to the floor via a fixed joint as it cannot be moved." The decision depends on
the semantics of the pair, so it is a table (``config/support_joints.yaml``): pair rules first
(most specific), then per-child-class rules, then layout nodes, then the class table's
``movable`` flag, then the default.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from recon_core.config import CONFIG_DIR, Settings, load_config, setting

DEFAULT_JOINTS_FILE = CONFIG_DIR / "support_joints.yaml"
SUPPORT_JOINTS = ("fixed", "floating")
#: Wildcard class name in pair rules.
ANY = "*"


@dataclass
class PairRule(Settings):
    parent: str = ANY
    child: str = ANY
    joint: str = setting("fixed", choices=SUPPORT_JOINTS)


@dataclass
class SupportJointTable(Settings):
    """The rules; ``resolve`` applies them in order of specificity."""

    default: str = setting("fixed", choices=SUPPORT_JOINTS)
    #: Joint of children whose class is movable in config/classes.yaml.
    movable: str = setting("floating", choices=SUPPORT_JOINTS)
    #: Joint of layout children (walls on the floor); layout never floats.
    layout: str = setting("fixed", choices=SUPPORT_JOINTS)
    classes: dict[str, str] = setting(default_factory=dict, choices=SUPPORT_JOINTS)
    pairs: list[PairRule] = field(default_factory=list)
    #: Mass (kg) of every object link in the exported tree (the paper's URDF uses 5 kg).
    object_mass: float = setting(5.0, min=0.0)

    def resolve(self, parent_class: str, child_class: str, child_movable: bool, child_is_layout: bool) -> str:
        """Joint type of the support edge parent -> child."""
        best: tuple[int, str] | None = None
        for rule in self.pairs:
            if rule.parent not in (ANY, parent_class) or rule.child not in (ANY, child_class):
                continue
            specificity = (rule.parent != ANY) + (rule.child != ANY)
            if best is None or specificity > best[0]:
                best = (specificity, rule.joint)
        if best is not None and best[0] > 0:
            return best[1]
        if child_class in self.classes:
            return self.classes[child_class]
        if child_is_layout:
            return self.layout
        if best is not None:  # a "* -> *" rule
            return best[1]
        return self.movable if child_movable else self.default


def load_support_joints(path: str | Path | None = None) -> SupportJointTable:
    """Read the joint table (default ``config/support_joints.yaml`` when it exists)."""
    if path is None and DEFAULT_JOINTS_FILE.is_file():
        path = DEFAULT_JOINTS_FILE
    return load_config(SupportJointTable, path or None)
