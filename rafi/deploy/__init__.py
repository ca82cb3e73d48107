"""Running a model on the machine (issue 14): the streaming compensator
(:mod:`rafi.deploy.compensator`, NumPy only) and its sample-by-sample filters
(:mod:`rafi.deploy.streaming`); ``docs/deploy.md``."""
