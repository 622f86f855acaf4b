"""boomtip's tools: the command line, the chains that wire a pipeline to an estimator, the run's
configuration (processing settings, scenarios), reports and the rerun recording, benchmarks and
studies."""
