"""Robot jobs for the controller: Yaskawa INFORM (``.JBI``) files read, compensated with a model and written back."""

from app.jobs.arm_ik import ArmIk, IkResult
from app.jobs.compensate import HOME_DEG, Compensation, JobCompensator, PointResult
from app.jobs.jbi import JOB_POSTYPES, Job, JobError, JobPosition, parse_job, read_job, write_job

__all__ = ["HOME_DEG", "JOB_POSTYPES", "ArmIk", "Compensation", "IkResult", "Job", "JobCompensator", "JobError",
           "JobPosition", "PointResult", "parse_job", "read_job", "write_job"]
