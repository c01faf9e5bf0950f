"""The host side of training: the loop between jitted calls, vmapped seed groups, run folders, checkpoints and
metrics logging."""
