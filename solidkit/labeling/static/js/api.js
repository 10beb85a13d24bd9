// Talking to the server: JSON over same-origin fetch. Every write carries X-Solidkit: 1 (the
// server refuses writes without it: cross-site forms cannot set it). A 401 (the server was
// restarted, the session is gone) asks `api.onUnauthorized` to log in again, then repeats the
// request once: an unsaved mark goes through after the login instead of being lost.

export class ApiError extends Error {
  constructor(status, body) {
    super((body && body.detail) || `HTTP ${status}`);
    this.status = status;
    this.body = body;
  }
}

async function call(method, url, body, retry = true) {
  const init = { method, credentials: 'same-origin', headers: { Accept: 'application/json' } };
  if (body !== undefined) {
    init.headers['Content-Type'] = 'application/json';
    init.headers['X-Solidkit'] = '1';
    init.body = JSON.stringify(body);
  }
  const res = await fetch(url, init);
  let data = null;
  try { data = await res.json(); } catch { data = null; }
  if (res.status === 401 && retry && api.onUnauthorized && !url.startsWith('/api/session')) {
    await api.onUnauthorized();
    return call(method, url, body, false);
  }
  if (!res.ok) throw new ApiError(res.status, data);
  return data;
}

export const api = {
  onUnauthorized: null,
  session: () => call('GET', '/api/session'),
  login: (name, token) => call('POST', '/api/session', { name, token: token || '' }),
  logout: () => call('POST', '/api/logout', {}),
  campaign: () => call('GET', '/api/campaign'),
  queue: kind => call('GET', `/api/queue/${kind}`),
  item: (kind, key, blind) => call('GET', `/api/item?kind=${encodeURIComponent(kind)}&key=${encodeURIComponent(key)}${blind ? '&blind=true' : ''}`),
  put: body => call('PUT', '/api/label', body),
  undo: body => call('POST', '/api/undo', body),
  verdict: body => call('POST', '/api/verdict', body),
  note: body => call('POST', '/api/note', body),
  agreement: () => call('GET', '/api/agreement'),
};

export const imageUrl = {
  preview: id => `/api/img/${id}/preview.jpg`,
  tile: (id, col, row) => `/api/img/${id}/tile/${col}/${row}.jpg`,
  crop: (id, x, y, w, h, out) => `/api/img/${id}/crop.jpg?x=${x}&y=${y}&w=${w}&h=${h}&out=${out}`,
};
