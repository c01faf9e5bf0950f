"""What is done with a trained run: load its policy, evaluate, export, render videos, sweep physics, plot and
report."""
