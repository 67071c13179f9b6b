"""Measurement programs (benchmarks, figures, A/B timings; never pass/fail tests), listed by
:mod:`glraster.studies.registry` and run by ``glraster study NAME`` (``glraster study
--list``): the benchmark, fill limit, stress sweeps, distortion figure, antialiasing study,
pyrender cross-check, the differentiable ops' benchmark and its plain-PyTorch yardsticks,
the service's load test, the figure scripts of the docs and the A/B studies."""
