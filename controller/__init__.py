"""The 400 µs model-based controller: trajectory interpolation, IK, feed-forward, telegrams."""
