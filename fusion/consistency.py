"""Whether a filter's covariance is honest, without truth: the normalised innovations squared
(NIS) of its updates. An honest filter's NIS per degree of freedom averages 1; well below, its
measurement noises are stated with margin; well above, its covariance is too small and its
sigmas say more than it knows."""

from __future__ import annotations

__all__ = ["NIS_TOO_LARGE", "nis_summary", "overconfident_notes"]

NIS_TOO_LARGE = 3.0  # innovations this much beyond their predicted covariance: the filter is overconfident


def nis_summary(nis: dict[str, list[float]]) -> dict[str, dict]:
    """Per update kind ([sum of NIS, sum of degrees of freedom, updates]), the mean NIS per
    degree of freedom and the number of updates."""
    return {kind: {"per_dof": round(s / dof, 4), "updates": int(n)} for kind, (s, dof, n) in nis.items() if dof > 0}


def overconfident_notes(summary: dict[str, dict], who: str) -> list[str]:
    """A note for each update kind whose innovations exceed NIS_TOO_LARGE times their covariance."""
    return [f"{who}: the {kind} updates' innovations are {v['per_dof']:.1f} times what the filter's covariance "
            "predicts (NIS per degree of freedom, 1 when consistent): its sigmas are too small here"
            for kind, v in summary.items() if v["per_dof"] > NIS_TOO_LARGE]
