"""The faces over the one vectorized core: Gymnasium (single and vector), PettingZoo, rsl-rl, their spaces
and rendering."""
