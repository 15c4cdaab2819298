"""Multi-target tracking at the base station (paper 004): grid fusion of each scan's detections
into position reports, the target fit that places them, online MCMCDA, and the tracker that
joins them."""
