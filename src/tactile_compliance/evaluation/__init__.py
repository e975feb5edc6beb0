"""Evaluation: re-scoring runs (``evaluate``), the paper's tables (``tables``), figures
(``plots``) and the report (``report``). The metrics themselves live in
``tactile_compliance.runs.metrics``, shared with training and inference."""
