"""Everything after the data exists: loading Ds and Df, sample selection, models, fits, γ, export."""

if __name__ != "thrustmap.fitting":  # the checkout's top-level folder, imported by its bare name
    raise ImportError(f"import thrustmap.fitting, not {__name__}: one module, one name")
