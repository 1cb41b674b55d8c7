"""Records to numbers: success rates with intervals, gaps, sensitivity, agreement, coverage, the run summary."""
