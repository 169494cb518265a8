"""API schemas of accounts, tokens, groups and the audit trail."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from backend.schemas.common import PLAIN_NAME, UtcDatetime


class LoginIn(BaseModel):
    model_config = ConfigDict(
        json_schema_extra={"examples": [{"username": "ada", "password": "correct horse battery"}]}
    )

    username: str = Field(max_length=64, examples=["ada"])
    password: str = Field(max_length=256, examples=["correct horse battery"])


class Me(BaseModel):
    username: str
    role: str
    auth_enabled: bool


class UserIn(BaseModel):
    model_config = ConfigDict(
        json_schema_extra={"examples": [{"username": "ada", "password": "correct horse battery", "role": "member"}]}
    )

    username: str = Field(min_length=2, max_length=64, examples=["ada"])
    password: str = Field(min_length=8, max_length=256)
    role: Literal["admin", "member"] = "member"


class UserPatch(BaseModel):
    model_config = ConfigDict(json_schema_extra={"examples": [{"disabled": True}]})

    role: Literal["admin", "member"] | None = None
    disabled: bool | None = None


class UserOut(BaseModel):
    model_config = ConfigDict(from_attributes=True)
    id: int
    username: str
    role: str
    disabled: bool
    created_at: UtcDatetime


class TokenIn(BaseModel):
    model_config = ConfigDict(
        json_schema_extra={"examples": [{"name": "nightly upload script", "expires_in_days": 90}]}
    )

    name: Annotated[str, PLAIN_NAME] = Field(max_length=100, examples=["nightly upload script"])
    expires_in_days: int | None = Field(None, ge=1, le=3650, description="Omit for a token that does not expire.")


class TokenOut(BaseModel):
    model_config = ConfigDict(from_attributes=True)
    id: int
    name: str
    prefix: str
    created_at: UtcDatetime
    expires_at: UtcDatetime | None
    revoked_at: UtcDatetime | None
    last_used_at: UtcDatetime | None


class TokenCreated(TokenOut):
    token: str = Field(description="The secret; shown once, store it now.")


class GroupIn(BaseModel):
    model_config = ConfigDict(json_schema_extra={"examples": [{"name": "impact-lab", "members": ["ada", "bob"]}]})

    name: Annotated[str, PLAIN_NAME] = Field(min_length=2, max_length=64, examples=["impact-lab"])
    members: list[str] = Field(default_factory=list, description="Usernames.")


class GroupOut(BaseModel):
    id: int
    name: str
    members: list[str]


class AuditOut(BaseModel):
    model_config = ConfigDict(from_attributes=True)
    id: int
    at: UtcDatetime
    username: str
    action: str
    object_type: str
    object_id: str
    detail: dict[str, Any]
