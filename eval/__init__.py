"""Evaluation and reports: scores policies on the same episodes and writes tables and figures."""
