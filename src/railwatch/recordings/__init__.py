"""Real recordings: layouts, readers, preparation, detection along the track."""
