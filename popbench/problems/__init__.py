"""Multi-robot problems: the distributed problem (distributed), how a graph is split among robots
(partition), the synthetic problems (synthetic) and the SLAM-shaped maps (slam_maps).
"""
