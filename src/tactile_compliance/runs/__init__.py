"""What training, evaluation and inference share about a run: checkpoints, the forward
path, metrics, the grids' results store and the run directory's names (``layout``).

This layer sits below training, evaluation and inference, so none has to import another.
"""
