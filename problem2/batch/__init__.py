"""The batch machinery of ``python train.py`` and the studies: worker processes, the progress
line, atomic writes (``plumbing``), the command line (``cli``), staging, manifest and code
version of a batch of runs (``experiments``). The learner never imports it."""
