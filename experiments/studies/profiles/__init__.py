"""The identifiability study: converged profiles of the data cost at lambda = 0, their result
types and report."""
