"""Reserved for later issues (see the roadmap in the README)."""
