"""The final evaluation of a trained run (``transam evaluate``): :mod:`~transam.evaluation.final`
plays the episodes and writes the results, :mod:`~transam.evaluation.probe` asks what the
embeddings encode about the partner, :mod:`~transam.evaluation.figure` draws them.

Not to be confused with the evaluation *during* training, a summary of the same rollout
(:mod:`transam.train.episodes`) logged to metrics.jsonl at every chunk.
"""
