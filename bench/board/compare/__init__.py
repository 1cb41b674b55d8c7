"""Statistics of `bench compare` (which of two policies is better): the group-sequential design (`design`), a
look's tests pooled and per cell (`looks`), and the unpaired comparison of two recorded runs (`unpaired`)."""
