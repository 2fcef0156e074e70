"""Evaluation: observers run on measurements (isolated processes), estimates scored against the truth."""
