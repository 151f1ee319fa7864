"""A run on disk: its folder, its checkpoints, and the deployable policy loaded from it."""
