"""Detection on recordings: a detector trained on a vehicle's recordings (``pipeline``: the
training windows, the model's ``recording.json``, ``detect`` along a recording, its events and
plot) and run on them sample block by sample block (``stream``: onboard, bounded memory).
"""
