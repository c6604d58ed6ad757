"""C sources and the build of the FMI 2.0 co-simulation FMUs (robot plant, servo drive)."""
