"""Training what the stages load: the autoencoder feature (`encoder`, the body of
`rodctl train-encoder`, on the centerlines `collection` gathers through the simulator), the
quick encoder of `feature.checkpoint: auto` (`auto`) and the learned Jacobian model (`learned`,
the body of `rodctl train-model`).

Stages never import this package (docs/development.md, the import contracts in pyproject.toml):
the commands train first, then build the method from the files they wrote.
"""

from rodctl.training.auto import auto_checkpoint, prepare_feature

__all__ = ["auto_checkpoint", "prepare_feature"]
