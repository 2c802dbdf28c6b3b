"""Weight surveys: frame sources (files, video), species and stock coefficients, the run over
worker processes, and the outputs (OUT.json, CSV, plot). The per-pair maths is vision.survey."""
