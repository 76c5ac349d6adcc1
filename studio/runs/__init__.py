"""Training runs: the run manager and its queue, the SQLite registry, the executors that start
trainers, and what the studio reads of a run folder (metrics, summaries, checkpoints)."""
