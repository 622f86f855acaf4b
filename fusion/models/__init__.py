"""The hook filter's own process and measurement models, built on the crane's nominal model
(:mod:`boomtip.data.crane_model`), never on the truth simulation."""
