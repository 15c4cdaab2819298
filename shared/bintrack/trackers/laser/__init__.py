"""Line (laser) sensors (paper 003): the adaptive basis algorithm and its base-station tracker."""
