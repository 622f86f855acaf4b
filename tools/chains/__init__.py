"""Chains: a pipeline (perception) and an estimator (fusion) wired together per frame, and the one runner."""
