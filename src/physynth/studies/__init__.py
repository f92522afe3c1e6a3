"""Studies built on the public API: each one a function that runs, scores and writes one experiment."""
