"""Pose-graph files: reading (read), their line formats (format), the value ranges checked at load
(limits), writing (write).
"""
