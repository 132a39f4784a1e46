"""Evaluation: scoring estimates against truth, the demo pipeline and experiments."""

from radiopose.evaluate.scoring import ErrorStats, MethodScore, error_stats, match_truth, score

__all__ = ["ErrorStats", "MethodScore", "error_stats", "match_truth", "score"]
