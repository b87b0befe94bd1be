"""The premise a controller is designed and certified under: its numbers chosen from an error
model and the training flights (docs/guarantee.md, "The premise")."""
