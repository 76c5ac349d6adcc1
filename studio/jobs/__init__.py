"""Background jobs (evals, video renders): one queue and worker per kind, each job a `mimickit`
child process."""
