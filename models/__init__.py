"""The value network of the forward reachable tube: contract, dynamics, training, export, evaluation.

Only `reach.contract` and `reach.dynamics` are imported by the service; they never import torch.
"""
