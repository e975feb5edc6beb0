"""What training, evaluation and inference share about a run.

Checkpoints (``checkpoint``), the forward path (``forward``), metrics (``metrics``), the
results store of grids (``results``) and the names of a run directory and its files
(``layout``). This layer sits below training, evaluation and inference, so none of them
has to import another.
"""
