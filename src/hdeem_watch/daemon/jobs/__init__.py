"""SLURM jobs: the pure job book and the typed job records it keeps."""
