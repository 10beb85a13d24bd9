// Talking to the server: JSON over same-origin fetch. Every write carries X-Solidkit: 1 (the
// server refuses writes without it: cross-site forms cannot set it).

export class ApiError extends Error {
  constructor(status, body) {
    super((body && body.detail) || `HTTP ${status}`);
    this.status = status;
    this.body = body;
  }
}

async function call(method, url, body) {
  const init = { method, credentials: 'same-origin', headers: { Accept: 'application/json' } };
  if (body !== undefined) {
    init.headers['Content-Type'] = 'application/json';
    init.headers['X-Solidkit'] = '1';
    init.body = JSON.stringify(body);
  }
  const res = await fetch(url, init);
  let data = null;
  try { data = await res.json(); } catch { data = null; }
  if (!res.ok) throw new ApiError(res.status, data);
  return data;
}

export const api = {
  session: () => call('GET', '/api/session'),
  login: token => call('POST', '/api/session', { token }),
  campaign: () => call('GET', '/api/campaign'),
  queue: kind => call('GET', `/api/queue/${kind}`),
  item: (kind, key) => call('GET', `/api/item?kind=${encodeURIComponent(kind)}&key=${encodeURIComponent(key)}`),
  put: body => call('PUT', '/api/label', body),
  undo: body => call('POST', '/api/undo', body),
};

export const imageUrl = {
  preview: id => `/api/img/${id}/preview.jpg`,
  tile: (id, col, row) => `/api/img/${id}/tile/${col}/${row}.jpg`,
  crop: (id, x, y, w, h, out) => `/api/img/${id}/crop.jpg?x=${x}&y=${y}&w=${w}&h=${h}&out=${out}`,
};
