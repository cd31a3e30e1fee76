"""Everything after the data exists: loading Ds and Df, sample selection, models, fits, γ, export."""
