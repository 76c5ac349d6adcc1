"""Running a training or a test: its arguments, its inputs, its record and the torchrun environment
(the run folder's names are `mimickit.learning.run_folder`, which the agent writes too);
`mimickit/run.py` is the entry that uses them."""
