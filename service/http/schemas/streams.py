"""What the streaming routes send, for ``responses=`` (their bodies are not JSON models)."""

from __future__ import annotations

from service.http.schemas.common import Job
from service.http.schemas.datasets import DatasetData

#: GET /api/jobs/{id}/events
JOB_EVENTS = {
    200: {
        "description": "Server-sent events: `progress` on every change and `end` at the finish, each with the job "
        f'as JSON ({Job.__name__}); `error` (data: `{{"detail", "field", "status"}}`) if the '
        "token is revoked meanwhile; `: heartbeat` comments while nothing changes",
        "content": {
            "text/event-stream": {
                "schema": {
                    "type": "string",
                    "example": 'event: progress\ndata: {"id": "job_…", "state": "running", "progress": 0.4, …}\n\n',
                }
            }
        },
    }
}

#: GET /api/datasets/{id}/data, by ``format``
DATASET_DOWNLOADS = {
    200: {
        "description": "The samples, streamed, in the requested format",
        "model": DatasetData,
        "content": {
            "text/csv": {
                "schema": {"type": "string", "description": "header t,u_y,x_y,u_z,x_z (s, V, µm); every sample"}
            },
            "application/x-ndjson": {
                "schema": {
                    "type": "string",
                    "description": (
                        'a first line {"id", "sample_rate_hz", "units", "columns", "samples", "rows_per_line"}, then one line '
                        'per chunk of rows {"start", "t_s": [...], …}'
                    ),
                }
            },
            "application/x-hdf5": {
                "schema": {
                    "type": "string",
                    "format": "binary",
                    "description": ("one dataset per array (unit attribute), the metadata as attributes"),
                }
            },
        },
    }
}
