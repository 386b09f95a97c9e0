"""Cross-view association metrics and reports."""
