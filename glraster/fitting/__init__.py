"""What the fits of ``glraster fit`` share, framework-free (NumPy only): the scenes and
their random draws (:mod:`.scenes`), the result records (:mod:`.results`) and the figures
(:mod:`.figures`, drawing through a front end's renderer). The fits themselves live in
:mod:`glraster.torch.fitting` and :mod:`glraster.jax.fitting`."""
