"""Recordings, the data source: a recording's layout, the readers of its file formats, its
preparation (resampling to the model's rate, the wheel comb). Detection on recordings is
:mod:`railwatch.detection`."""
