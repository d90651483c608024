"""End-to-end benchmarking of the pipeline: one configuration (a preset plus overrides) through map ->
contact graph -> CAD replacement on a generated scene, timed per stage and scored against its ground
truth (`pipeline`); the named suites behind `scene-recon benchmark` (`suites`); the report (`report`)."""
