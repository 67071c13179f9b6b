"""PyTorch autograd wrappers of :mod:`glraster.diff` with nvdiffrast's signatures (the only
module that imports torch; optional extra ``[torch]``)."""
