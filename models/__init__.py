"""The value network of the forward reachable tube: contract, dynamics, training, export, evaluation.

Only `models.contract` and `models.dynamics` are imported by the service; they never import torch.
"""
