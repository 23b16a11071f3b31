"""`ccf study`: the paper's experiments on recorded and simulated data, with a verdict per claim."""
