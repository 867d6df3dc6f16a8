"""How well the improved method told moving points from static ones, against the log's labels."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..io.mcap_log import LogReader


def segmentation_scores(out_dir: Path, method: str, labels: dict[int, np.ndarray] | None,
                        notes: list[str]) -> dict[str, float | int | None] | None:
    """Precision, recall, F1 (and counts) of ``method``'s per-point verdicts in ``processed.mcap``
    against ``/ground_truth/point_labels``; None, with the reason added to ``notes``, where it
    cannot be scored."""
    if labels is None:
        notes.append("the log has no /ground_truth/point_labels: segmentation cannot be scored")
        return None
    proc = out_dir / "processed.mcap"
    tp = fp = fn = 0
    seen = verdicts = unlabelled = other_length = 0
    for msg in LogReader(proc).messages([f"/{method}/moving_labels"]):
        verdicts += 1
        est = np.frombuffer(bytes(msg.msg.moving), np.uint8).astype(bool)
        ref = labels.get(msg.log_time_ns)
        if ref is None or ref.shape != est.shape:
            unlabelled += ref is None
            other_length += ref is not None
            continue
        ref = ref.astype(bool)
        tp += int(np.sum(est & ref))
        fp += int(np.sum(est & ~ref))
        fn += int(np.sum(~est & ref))
        seen += 1
    if verdicts == 0:
        notes.append("no per-point moving verdicts in processed.mcap (Doppler was off): segmentation not scored")
        return None
    if seen < verdicts:  # the labels do not fit those sweeps: a damaged or foreign label topic
        notes.append(f"{verdicts - seen} of {verdicts} sweeps not scored for segmentation: {unlabelled} without "
                     f"a /ground_truth/point_labels message at their stamp, {other_length} whose labels are not "
                     "one per point")
    if seen == 0:
        return None
    precision = tp / (tp + fp) if tp + fp else None
    recall = tp / (tp + fn) if tp + fn else None
    f1 = 2 * precision * recall / (precision + recall) if precision and recall else None
    if tp + fn == 0:
        notes.append("no point of the log hit a mover: recall is undefined")
    return {"precision": precision, "recall": recall, "f1": f1, "true_positives": tp, "false_positives": fp,
            "false_negatives": fn}
