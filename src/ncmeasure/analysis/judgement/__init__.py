"""What the friction says: diagnosis along the travel, verdicts, summaries, comparisons."""
