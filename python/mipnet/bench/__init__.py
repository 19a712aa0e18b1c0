"""Benchmarks against torch and OpenVINO (``python -m mipnet.bench ops|model``): per-kernel rows
(:mod:`~mipnet.bench.ops`), whole-network eval and training steps (:mod:`~mipnet.bench.model`) and the
machine header every timing prints (:mod:`~mipnet.bench.machine`)."""
