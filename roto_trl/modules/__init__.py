"""Agent networks (encoder, policy and value heads) as TensorDict modules: see the training issue."""
