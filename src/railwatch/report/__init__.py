"""Reports: tables, figures, the benchmark's HTML report and the detection plot. They draw
what the data, the detectors and the evaluation produced; they never produce data themselves."""
