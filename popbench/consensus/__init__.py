"""From the robots' local estimates to one global estimate: the information-weighted ADMM consensus
(admm) and its team system (system), the frames' rigid alignment (alignment), and the step every
local method shares (reconcile).
"""
