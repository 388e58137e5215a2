"""Long measurements, run as `.venv/bin/python -m benchmarks.<name>`; each writes benchmarks/results/<name>.md."""
