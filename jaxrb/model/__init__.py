"""The three kinds of data and their checks: Model, Params, State, options, shapes."""
