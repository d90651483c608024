"""Say why a recording gave no usable frame, and what to do about it (for `map`, `run` and `inspect`)."""

from __future__ import annotations

from typing import Any

#: What each skip counter means, and the usual remedy.
_HINTS = {
    "no_pose": "frames without a camera pose",
    "all_depth_invalid": ("frames without one valid depth pixel (0 / 65535 / NaN everywhere): check the depth "
                          "topic or the depth scale (config/data.yaml depth_scale)"),
    "unpaired_depth": ("depth images without a colour image within sync_slop_s: check the stamps or raise "
                       "sync_slop_s (config/data.yaml)"),
    "unpaired_color": "colour images without a depth image",
    "unpaired": "colour images without a matching depth image",
    "non_monotonic": "images whose stamps go backwards",
    "bad_image": "frames whose images cannot be used",
    "unreadable": "frames whose image files cannot be read",
    "size_mismatch": "frames whose colour and depth sizes cannot be reconciled",
}


def skip_reasons(loader: Any) -> dict[str, int]:
    """Non-zero skip counters plus the most frequent detailed reasons of a loader (after a pass)."""
    out = {k: v for k, v in loader.skips.as_dict().items() if v and k != "tf_conflicts"}
    for reason, n in loader.skips.reasons.most_common(5):
        out[reason] = n
    return out


def pose_hint(loader: Any) -> str:
    """Why frames have no pose: the TF diagnosis of a bag, or the notes of a frame folder."""
    if hasattr(loader, "pose_hint"):
        return str(loader.pose_hint())
    notes = getattr(loader, "notes", [])
    return "; ".join(notes) if notes else "no pose file for these frames"


def explain_empty(loader: Any, source: object = "") -> str:
    """One message on why `loader` yielded no frame (call after iterating it), naming the remedy."""
    skips = loader.skips.as_dict()
    where = f"{source}: " if source else ""
    parts: list[str] = []
    if skips.get("no_pose"):
        parts.append(f"{skips['no_pose']} frames have no camera pose: {pose_hint(loader)}")
    for key in ("all_depth_invalid", "size_mismatch", "bad_image", "unreadable", "unpaired_depth", "unpaired",
                "non_monotonic"):
        if skips.get(key):
            detail = ""
            if key in ("size_mismatch", "bad_image", "unreadable") and loader.skips.reasons:
                detail = f" (e.g. {loader.skips.reasons.most_common(1)[0][0]})"
            parts.append(f"{skips[key]} {_HINTS[key]}{detail}")
    if getattr(loader, "truncated", False):
        parts.append("the recording is truncated (" + "; ".join(getattr(loader, "damage", [])) + ")")
    if not parts:
        total = len(loader) if hasattr(loader, "__len__") else None
        parts.append("the source holds no colour/depth frame" if not total else "every frame was filtered out")
    return f"{where}no usable frame: " + "; ".join(parts)
