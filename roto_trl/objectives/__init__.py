"""Self-supervised auxiliary objectives as TorchRL ``LossModule``s: see the SSL issue."""
