"""The teacher: DINO attention → prompts → SAM2, and the weights it loads."""
